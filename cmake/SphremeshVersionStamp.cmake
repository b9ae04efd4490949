# Script mode (-P): writes sph_version.f90 only when its text changes, so no needless rebuilds.
find_package(Git QUIET)
set(GIT_HASH "unknown")
if(GIT_FOUND)
    execute_process(COMMAND ${GIT_EXECUTABLE} -C ${SRC_DIR} describe --always --dirty --abbrev=12
        OUTPUT_VARIABLE GIT_HASH OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET RESULT_VARIABLE rc)
    if(NOT rc EQUAL 0 OR GIT_HASH STREQUAL "")
        set(GIT_HASH "unknown")
    endif()
endif()
configure_file(${IN} ${OUT}.tmp @ONLY)
file(COPY_FILE ${OUT}.tmp ${OUT} ONLY_IF_DIFFERENT)
file(REMOVE ${OUT}.tmp)
