!> Working precision and integer kinds. The one place the project's kinds are chosen; the
!> matching MPI datatypes live in sph_mpi_env and the HDF5 ones in sph_hdf5.
module sph_kinds
    use, intrinsic :: iso_fortran_env, only: real64, int32, int64
    implicit none
    private
    public :: wp, i4, i8

    integer, parameter :: wp = real64  !< working real kind
    integer, parameter :: i4 = int32   !< ordinary integers written to files
    integer, parameter :: i8 = int64   !< global particle ids: survive migration and remeshing
end module sph_kinds
