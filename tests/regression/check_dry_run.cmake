# --check: the input is checked and the run set up and described, and nothing is written.
file(REMOVE_RECURSE ${WORKDIR})
file(MAKE_DIRECTORY ${WORKDIR})
execute_process(COMMAND ${MPIEXEC} ${NP_FLAG} ${NP} ${EXTRA} ${PROGRAM} --check ${INPUT}
    WORKING_DIRECTORY ${WORKDIR} OUTPUT_VARIABLE out ERROR_VARIABLE err RESULT_VARIABLE rc
    TIMEOUT 60)
if(NOT rc EQUAL 0)
    message(FATAL_ERROR "--check exited with '${rc}':\n${out}\n${err}")
endif()
# SHIPPED: one of the inputs in input/, of which only the verdict is known here
# the memory, measured (an estimate of the particle fields alone was 1.4-2.7 times low)
set(memory "check: memory +[0-9.]+ MB on the largest rank, +[0-9.]+ MB over all ranks .*measured after the set-up")
if(SHIPPED)
    set(expects "${memory}" "check: the input is valid")
    # a run that remeshes: the remesh's memory too (nothing was said of it)
    file(READ ${INPUT} text)
    string(REGEX MATCH "\n *mode *= *'(same|refine|coarsen)'" remesh "${text}")
    if(remesh)
        list(APPEND expects "check: &remesh mode = '${CMAKE_MATCH_1}': .*MB")
    endif()
    # a multi-resolution run: its virtual particles counted apart (they were counted as
    # real and, by --check, as walls)
    if(text MATCHES "\n *&region")
        list(APPEND expects
            "particles: [0-9]+ real \\(fluid [0-9]+\\), [0-9]+ virtual, load imbalance"
            "check: level 1: [0-9]+ particles \\([0-9]+ fluid, [0-9]+ wall, [0-9]+ virtual\\)")
    endif()
elseif(HUGE_T_END)
    # t_end = 1e20: no step count beyond an integer's range; the default max_steps ends the
    # run long before (said nothing before)
    set(expects "check: more than 1e15 steps to t_end = +1\\.000E\\+020 s"
        "check: &run max_steps = 100000000 ends the run first, near t = "
        "check: the input is valid")
else()
    set(expects "check: level 0: 920 particles \\(800 fluid, 120 wall\\)"
        "${memory}" "check: first time step +1\\.320E-04 s, limited by viscous"
        "check: about 17[0-9] steps to t_end" "check: the input is valid")
endif()
foreach(expect ${expects})
    if(NOT out MATCHES "${expect}")
        message(FATAL_ERROR "--check output lacks '${expect}':\n${out}")
    endif()
endforeach()
file(GLOB created ${WORKDIR}/*)
if(created)
    message(FATAL_ERROR "--check wrote files: ${created}")
endif()
