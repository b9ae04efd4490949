# Run sphremesh under mpiexec in WORKDIR and compare the reported relative L2 error against
# the analytic solution with TOLERANCE (percent). Fails on a non-zero exit or a missing line.
file(REMOVE_RECURSE ${WORKDIR})
file(MAKE_DIRECTORY ${WORKDIR})
separate_arguments(EXTRA)
execute_process(COMMAND ${MPIEXEC} ${NP_FLAG} ${NP} ${EXTRA} ${PROGRAM} ${INPUT}
    WORKING_DIRECTORY ${WORKDIR}
    OUTPUT_VARIABLE out ERROR_VARIABLE err RESULT_VARIABLE rc)
message("${out}")
if(NOT rc EQUAL 0)
    message(FATAL_ERROR "sphremesh exited with ${rc}:\n${err}")
endif()
string(REGEX MATCH "error against the analytic [a-z]+ solution at t = +[0-9.E+-]+ s: relative L2 = +([0-9.]+) %" line "${out}")
if(NOT line)
    message(FATAL_ERROR "no analytic error line in the output")
endif()
set(error ${CMAKE_MATCH_1})
if(error GREATER ${TOLERANCE})
    message(FATAL_ERROR "relative L2 error ${error} % exceeds the tolerance ${TOLERANCE} %")
endif()
message(STATUS "relative L2 error ${error} % within ${TOLERANCE} %")
