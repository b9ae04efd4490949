# An unstable run must be stopped by the health checks: exit status 3 on every rank, one
# message matching EXPECT, no traceback, and the failure snapshot written.
file(REMOVE_RECURSE ${WORKDIR})
file(MAKE_DIRECTORY ${WORKDIR})
execute_process(COMMAND ${MPIEXEC} ${NP_FLAG} ${NP} ${EXTRA} ${PROGRAM} ${INPUT}
    WORKING_DIRECTORY ${WORKDIR} OUTPUT_VARIABLE out ERROR_VARIABLE err RESULT_VARIABLE rc
    TIMEOUT 120)
if(NOT rc EQUAL 3)
    message(FATAL_ERROR "expected exit status 3 (unhealthy run), got '${rc}':\n${err}")
endif()
include(${CMAKE_CURRENT_LIST_DIR}/expect_one_message.cmake)
file(GLOB failure_files ${WORKDIR}/output/*_failure_*.h5)
if(NOT failure_files)
    message(FATAL_ERROR "no failure snapshot in ${WORKDIR}/output")
endif()
