# Start sphremesh from a file of particles (&domain initial_particles).
#   MODE=run:   write the lattice of INPUT with MAKER (scripts/make_initial_particles.py), run
#               from it on NP ranks (MAX_STEPS: stop early) and compare SNAPSHOT with the one
#               in REFERENCE_DIR by COMPARER (scripts/sph_compare.py: bitwise,
#               every dataset but `rank`).
#               VARIANT: first rewrite the file with BREAKER (make_bad_particles.py VARIANT).
#   MODE=error: break the file with BREAKER (make_bad_particles.py VARIANT) and expect a
#               non-zero exit with exactly one error message matching EXPECT.
#   MODE=accept: as run, without the comparison: the run must read the file and finish
#               (and its log match EXPECT, when given; VARIANT as for run).
#   WALL_MODEL (any mode): the input's &numerics wall_model replaced by this one, for the
#               file and the run.
file(REMOVE_RECURSE ${WORKDIR})
file(MAKE_DIRECTORY ${WORKDIR})
separate_arguments(EXTRA)
set(particles ${WORKDIR}/particles.h5)
if(DEFINED WALL_MODEL)
    file(READ ${INPUT} text)
    string(REGEX REPLACE "wall_model = '[a-z_]*'" "wall_model = '${WALL_MODEL}'" text "${text}")
    if(NOT text MATCHES "wall_model = '${WALL_MODEL}'")
        message(FATAL_ERROR "${INPUT} has no wall_model = '...' to replace")
    endif()
    set(INPUT ${WORKDIR}/base.nml)
    file(WRITE ${INPUT} "${text}")
endif()
execute_process(COMMAND ${PYTHON} ${MAKER} ${INPUT} -o ${particles} RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${MAKER} failed (${rc})")
endif()
if(DEFINED VARIANT)
    set(good ${particles})
    set(particles ${WORKDIR}/${VARIANT}.h5)
    execute_process(COMMAND ${PYTHON} ${BREAKER} ${good} ${VARIANT} ${particles}
        RESULT_VARIABLE rc)
    if(NOT rc EQUAL 0)
        message(FATAL_ERROR "${BREAKER} failed (${rc})")
    endif()
endif()
# the input with the file named in &domain (and perhaps fewer steps)
file(READ ${INPUT} text)
string(REGEX REPLACE "&domain\n" "&domain\n    initial_particles = '${particles}'\n" text "${text}")
if(DEFINED MAX_STEPS)
    string(REGEX REPLACE "&run\n" "&run\n    max_steps = ${MAX_STEPS}\n" text "${text}")
endif()
file(WRITE ${WORKDIR}/input.nml "${text}")
execute_process(COMMAND ${MPIEXEC} ${NP_FLAG} ${NP} ${EXTRA} ${PROGRAM} ${WORKDIR}/input.nml
    WORKING_DIRECTORY ${WORKDIR} OUTPUT_VARIABLE out ERROR_VARIABLE err RESULT_VARIABLE rc)
message("${out}")
if(MODE STREQUAL "error")
    if(rc EQUAL 0)
        message(FATAL_ERROR "expected a non-zero exit, got 0")
    endif()
    if(NOT err MATCHES "${EXPECT}")
        message(FATAL_ERROR "stderr does not match '${EXPECT}':\n${err}")
    endif()
    string(REGEX MATCHALL "sphremesh: error" hits "${err}")
    list(LENGTH hits n)
    if(NOT n EQUAL 1 OR err MATCHES "Backtrace|#0 ")
        message(FATAL_ERROR "expected exactly one error message and no traceback:\n${err}")
    endif()
    message(STATUS "refused as expected: ${err}")
    return()
endif()
if(NOT rc EQUAL 0)
    message(FATAL_ERROR "sphremesh exited with ${rc}:\n${err}")
endif()
if(NOT out MATCHES "particles: read from ")
    message(FATAL_ERROR "the run did not read the particle file")
endif()
if(MODE STREQUAL "accept")
    if(DEFINED EXPECT AND NOT "${out}${err}" MATCHES "${EXPECT}")
        message(FATAL_ERROR "the log does not match '${EXPECT}':\n${out}${err}")
    endif()
    return()
endif()
execute_process(COMMAND ${PYTHON} ${COMPARER} ${REFERENCE_DIR}/${SNAPSHOT}
    ${WORKDIR}/output/${SNAPSHOT} OUTPUT_VARIABLE cmp ERROR_VARIABLE cmp_err
    RESULT_VARIABLE rc)
message("${cmp}${cmp_err}")
if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${SNAPSHOT} differs from the lattice run's")
endif()
