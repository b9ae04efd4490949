# Compile the git hash and the build options into the code (printed by --version and every run).
# The hash is taken at build time, so a rebuild after a commit reports the new one.
set(SPHREMESH_BUILD_OPTIONS
    "type=${CMAKE_BUILD_TYPE} compiler=${CMAKE_Fortran_COMPILER_ID}-${CMAKE_Fortran_COMPILER_VERSION} native=${SPHREMESH_NATIVE} mpi=${MPI_Fortran_VERSION} hdf5=${HDF5_VERSION}")
set(SPHREMESH_VERSION_IN ${CMAKE_CURRENT_LIST_DIR}/sph_version.f90.in)
set(SPHREMESH_VERSION_OUT ${CMAKE_BINARY_DIR}/generated/sph_version.f90)
add_custom_target(sphremesh_version_stamp
    COMMAND ${CMAKE_COMMAND}
        -DSRC_DIR=${CMAKE_SOURCE_DIR}
        -DIN=${SPHREMESH_VERSION_IN}
        -DOUT=${SPHREMESH_VERSION_OUT}
        -DVERSION=${PROJECT_VERSION}
        "-DOPTIONS=${SPHREMESH_BUILD_OPTIONS}"
        -P ${CMAKE_CURRENT_LIST_DIR}/SphremeshVersionStamp.cmake
    BYPRODUCTS ${SPHREMESH_VERSION_OUT}
    COMMENT "Stamping git hash into sph_version.f90")
