# A run whose t_end was shortened below an entry of &output output_times: it runs to the end
# (status 0), notes the skipped entry, and writes its last state.
# -DMPIEXEC -DNP_FLAG -DNP -DEXTRA -DPROGRAM -DINPUT -DWORKDIR
file(REMOVE_RECURSE "${WORKDIR}")
file(MAKE_DIRECTORY "${WORKDIR}")
separate_arguments(_extra UNIX_COMMAND "${EXTRA}")
execute_process(COMMAND ${MPIEXEC} ${NP_FLAG} ${NP} ${_extra} ${PROGRAM} ${INPUT}
    WORKING_DIRECTORY "${WORKDIR}" OUTPUT_VARIABLE out ERROR_VARIABLE err RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
    message(FATAL_ERROR "expected status 0, got ${rc}\n${out}\n${err}")
endif()
if(NOT out MATCHES "note: &output output_times: 1 entry past t_end = 1\\.000E-03 s skipped")
    message(FATAL_ERROR "no note about the skipped output time:\n${out}")
endif()
file(GLOB _snaps "${WORKDIR}/output/poiseuille_*.h5")
list(LENGTH _snaps n)
if(n LESS 2)
    message(FATAL_ERROR "expected the first and last snapshots, found: ${_snaps}")
endif()
