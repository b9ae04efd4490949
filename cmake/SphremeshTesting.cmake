# Unit tests written as pFUnit 4 .pf files, built either by a real pFUnit 4 (clusters) or by
# the project's own runner, cmake/pfunit_lite (everywhere else), from the same sources.
#
#   SPHREMESH_PFUNIT = AUTO (default): real pFUnit if find_package(PFUNIT 4) finds one
#                      ON:   insist on real pFUnit      OFF: always the project runner
#
#   sphremesh_add_pf_test(NAME <name> SOURCE <file.pf> [MAX_PES <n>] [BUILD_ONLY]
#                         LINK <targets...>)
# BUILD_ONLY builds the test program without registering it (the runner's deliberately
# failing programs, which are run by a checking test instead).
set(SPHREMESH_PFUNIT AUTO CACHE STRING "pFUnit for unit tests: AUTO, ON or OFF")
set_property(CACHE SPHREMESH_PFUNIT PROPERTY STRINGS AUTO ON OFF)
if(NOT SPHREMESH_PFUNIT MATCHES "^(AUTO|ON|OFF)$")
    message(FATAL_ERROR "SPHREMESH_PFUNIT='${SPHREMESH_PFUNIT}' must be AUTO, ON or OFF")
endif()

set(SPHREMESH_USING_REAL_PFUNIT FALSE)
if(SPHREMESH_PFUNIT STREQUAL "ON")
    find_package(PFUNIT 4 QUIET)
    if(NOT PFUNIT_FOUND)
        message(FATAL_ERROR
            "SPHREMESH_PFUNIT=ON but no pFUnit 4 was found. Point CMake at an install with "
            "-DCMAKE_PREFIX_PATH=<pfunit prefix> or -DPFUNIT_DIR=<prefix>/PFUNIT-4.x/cmake, "
            "or use -DSPHREMESH_PFUNIT=AUTO to fall back to the project's runner.")
    endif()
    set(SPHREMESH_USING_REAL_PFUNIT TRUE)
elseif(SPHREMESH_PFUNIT STREQUAL "AUTO")
    find_package(PFUNIT 4 QUIET)
    if(PFUNIT_FOUND)
        set(SPHREMESH_USING_REAL_PFUNIT TRUE)
    endif()
endif()

# Open MPI refuses root without these and more ranks than cores without --oversubscribe.
set(SPHREMESH_TEST_ENVIRONMENT "OMPI_ALLOW_RUN_AS_ROOT=1;OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1")
execute_process(COMMAND ${MPIEXEC_EXECUTABLE} --version OUTPUT_VARIABLE _sph_mpiexec_version
    ERROR_QUIET)
set(SPHREMESH_MPIEXEC_OVERSUBSCRIBE "")
if(_sph_mpiexec_version MATCHES "Open MPI|OpenRTE")
    set(SPHREMESH_MPIEXEC_OVERSUBSCRIBE "--oversubscribe")
endif()

if(SPHREMESH_USING_REAL_PFUNIT)
    message(STATUS "Unit tests: real pFUnit ${PFUNIT_VERSION}")
    if(SPHREMESH_MPIEXEC_OVERSUBSCRIBE AND NOT MPIEXEC_PREFLAGS MATCHES "oversubscribe")
        set(MPIEXEC_PREFLAGS ${MPIEXEC_PREFLAGS} ${SPHREMESH_MPIEXEC_OVERSUBSCRIBE})
    endif()
else()
    message(STATUS "Unit tests: the project's pFUnit runner (cmake/pfunit_lite)")
    find_package(Python3 COMPONENTS Interpreter REQUIRED)
    set(_pflite_dir ${CMAKE_BINARY_DIR}/pfunit_lite)
    set(_pflite_sources ${_pflite_dir}/pfunit_lite_core.F90 ${_pflite_dir}/pfunit_lite_asserts.F90
        ${_pflite_dir}/funit.F90 ${_pflite_dir}/pfunit.F90)
    add_custom_command(OUTPUT ${_pflite_sources}
        COMMAND ${Python3_EXECUTABLE} ${CMAKE_CURRENT_LIST_DIR}/pfunit_lite/pfproc.py support ${_pflite_dir}
        DEPENDS ${CMAKE_CURRENT_LIST_DIR}/pfunit_lite/pfproc.py
        COMMENT "Generating the pfunit_lite support library")
    add_library(pfunit_lite STATIC ${_pflite_sources})
    set_target_properties(pfunit_lite PROPERTIES Fortran_MODULE_DIRECTORY ${_pflite_dir}/modules)
    target_include_directories(pfunit_lite PUBLIC ${_pflite_dir}/modules)
    target_link_libraries(pfunit_lite PUBLIC MPI::MPI_Fortran)
    # generated specifics are long lines
    if(CMAKE_Fortran_COMPILER_ID STREQUAL "GNU")
        target_compile_options(pfunit_lite PRIVATE -ffree-line-length-none -Wno-unused-dummy-argument)
    endif()
endif()

function(sphremesh_add_pf_test)
    cmake_parse_arguments(T "BUILD_ONLY" "NAME;SOURCE;MAX_PES" "LINK" ${ARGN})
    if(NOT T_MAX_PES)
        set(T_MAX_PES 1)
    endif()
    if(SPHREMESH_USING_REAL_PFUNIT)
        add_pfunit_ctest(${T_NAME} TEST_SOURCES ${T_SOURCE} LINK_LIBRARIES ${T_LINK}
            MAX_PES ${T_MAX_PES})
        set_tests_properties(${T_NAME} PROPERTIES ENVIRONMENT "${SPHREMESH_TEST_ENVIRONMENT}")
        return()
    endif()
    file(READ ${T_SOURCE} _text)
    set(_gen ${CMAKE_CURRENT_BINARY_DIR}/${T_NAME}_pf)
    set(_module ${_gen}/${T_NAME}.F90)
    set(_driver ${_gen}/${T_NAME}_driver.F90)
    add_custom_command(OUTPUT ${_module} ${_driver}
        COMMAND ${CMAKE_COMMAND} -E make_directory ${_gen}
        COMMAND ${Python3_EXECUTABLE} ${PROJECT_SOURCE_DIR}/cmake/pfunit_lite/pfproc.py test
            ${T_SOURCE} ${_module} ${_driver}
        DEPENDS ${T_SOURCE} ${PROJECT_SOURCE_DIR}/cmake/pfunit_lite/pfproc.py
        COMMENT "pfunit_lite: ${T_NAME}.pf")
    add_executable(${T_NAME} ${_module} ${_driver})
    set_target_properties(${T_NAME} PROPERTIES Fortran_MODULE_DIRECTORY ${_gen}/modules
        RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
    target_link_libraries(${T_NAME} PRIVATE pfunit_lite ${T_LINK})
    if(CMAKE_Fortran_COMPILER_ID STREQUAL "GNU")
        target_compile_options(${T_NAME} PRIVATE -ffree-line-length-none)
    endif()
    if(T_BUILD_ONLY)
        return()
    endif()
    if(_text MATCHES "[Uu][Ss][Ee][ \t]+pfunit")
        add_test(NAME ${T_NAME} COMMAND ${MPIEXEC_EXECUTABLE} ${MPIEXEC_NUMPROC_FLAG} ${T_MAX_PES}
            ${SPHREMESH_MPIEXEC_OVERSUBSCRIBE} ${MPIEXEC_PREFLAGS} $<TARGET_FILE:${T_NAME}>
            ${MPIEXEC_POSTFLAGS})
        set_tests_properties(${T_NAME} PROPERTIES PROCESSORS ${T_MAX_PES})
    else()
        add_test(NAME ${T_NAME} COMMAND $<TARGET_FILE:${T_NAME}>)
    endif()
    set_tests_properties(${T_NAME} PROPERTIES ENVIRONMENT "${SPHREMESH_TEST_ENVIRONMENT}"
        TIMEOUT 600 FAIL_REGULAR_EXPRESSION "[1-9][0-9]* failed")
endfunction()
