# Shared by the checks of runs that must fail: their stderr (`err`) matches EXPECT, reports
# no traceback or crash, and holds exactly one 'sphremesh: error' message.
if(NOT err MATCHES "${EXPECT}")
    message(FATAL_ERROR "stderr does not match '${EXPECT}':\n${err}")
endif()
if(err MATCHES "Backtrace|#0 |Error termination|SIGSEGV|signal [0-9]+")
    message(FATAL_ERROR "a traceback or crash was reported:\n${err}")
endif()
string(REGEX MATCHALL "sphremesh: error" hits "${err}")
list(LENGTH hits n)
if(NOT n EQUAL 1)
    message(FATAL_ERROR "expected exactly one error message, got ${n}:\n${err}")
endif()
