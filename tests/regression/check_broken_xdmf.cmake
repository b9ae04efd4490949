# A copy of a good XDMF file with one dataset reference broken must be refused (exit 1) with
# a message naming the reference.
file(READ ${XDMF} text)
string(REPLACE "/particles/density<" "/particles/no_such_field<" broken "${text}")
get_filename_component(dir ${XDMF} DIRECTORY)
file(WRITE ${dir}/broken.xdmf "${broken}")
execute_process(COMMAND ${PYTHON} ${CHECKER} ${dir}/broken.xdmf RESULT_VARIABLE rc
    ERROR_VARIABLE err OUTPUT_VARIABLE out)
file(REMOVE ${dir}/broken.xdmf)
if(rc EQUAL 0)
    message(FATAL_ERROR "a broken XDMF reference was accepted")
endif()
if(NOT err MATCHES "no_such_field: no such dataset")
    message(FATAL_ERROR "the message does not name the broken reference:\n${err}")
endif()
