# A bad run must exit non-zero with one message matching EXPECT on stderr and no traceback.
execute_process(COMMAND ${PROGRAM} ${INPUT} OUTPUT_VARIABLE out ERROR_VARIABLE err
    RESULT_VARIABLE rc)
if(rc EQUAL 0)
    message(FATAL_ERROR "expected a non-zero exit, got 0")
endif()
include(${CMAKE_CURRENT_LIST_DIR}/expect_one_message.cmake)
