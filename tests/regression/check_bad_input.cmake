# One bad input (tests/regression/bad_inputs): run it on NP ranks in a fresh, empty WORKDIR and
# require a non-zero exit, stderr matching the file's `! expect: <regex>` line (or EXPECT when
# given), exactly one 'sphremesh: error' message, no traceback, and nothing created in WORKDIR
# (the input is checked before any work).
# -DMPIEXEC -DNP_FLAG -DNP -DEXTRA -DPROGRAM -DINPUT -DWORKDIR [-DEXPECT]
file(REMOVE_RECURSE "${WORKDIR}")
file(MAKE_DIRECTORY "${WORKDIR}")
if(NOT DEFINED EXPECT OR EXPECT STREQUAL "")
    file(STRINGS "${INPUT}" _lines REGEX "^! expect: ")
    list(LENGTH _lines _n)
    if(NOT _n EQUAL 1)
        message(FATAL_ERROR "${INPUT}: expected one '! expect: <regex>' line, found ${_n}")
    endif()
    string(REGEX REPLACE "^! expect: " "" EXPECT "${_lines}")
endif()
separate_arguments(_extra UNIX_COMMAND "${EXTRA}")
execute_process(COMMAND ${MPIEXEC} ${NP_FLAG} ${NP} ${_extra} ${PROGRAM} ${INPUT}
    WORKING_DIRECTORY "${WORKDIR}" OUTPUT_VARIABLE out ERROR_VARIABLE err
    RESULT_VARIABLE rc TIMEOUT 25)
if(rc EQUAL 0)
    message(FATAL_ERROR "expected a non-zero exit, got 0\nstdout:\n${out}\nstderr:\n${err}")
endif()
if(NOT rc MATCHES "^[0-9]+$")
    message(FATAL_ERROR "the run did not end normally: ${rc}\nstderr:\n${err}")
endif()
include(${CMAKE_CURRENT_LIST_DIR}/expect_one_message.cmake)
file(GLOB _made "${WORKDIR}/*" "${WORKDIR}/.*")
if(_made)
    message(FATAL_ERROR "the bad run created output before failing: ${_made}\n${err}")
endif()
