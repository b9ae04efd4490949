!> The one parallel HDF5 wrapper: files opened collectively on a communicator, row datasets
!> written and read collectively by (global rows, local rows, offset), attributes. Every rank
!> takes part in every call, also a rank with no rows (it selects nothing). Every HDF5 return
!> code is checked here; HDF5's own error printing is switched off in favour of our messages.
module sph_hdf5
    use, intrinsic :: iso_c_binding, only: c_loc, c_ptr, c_null_char
    use hdf5
    use mpi_f08, only: MPI_INFO_NULL
    use sph_kinds, only: wp, i4, i8
    use sph_errors, only: fatal_abort
    use sph_mpi_env, only: mpi_env_t, global_sum, exclusive_scan_i8
    implicit none
    private
    public :: h5_file_t, h5_create, h5_open_read, h5_close, check_h5, h5_group_create
    public :: h5_write_rows, h5_read_rows, h5_dataset_rows, h5_exists
    public :: h5_write_attribute, h5_read_attribute, h5_attribute_exists

    !> An open file and the collective transfer property used for its datasets.
    type :: h5_file_t
        integer(hid_t) :: id = -1
        integer(hid_t) :: xfer = -1
        character(len=:), allocatable :: path
    end type h5_file_t

    interface h5_write_rows
        module procedure write_rows_wp, write_rows_wp3, write_rows_i8, write_rows_i4
    end interface
    interface h5_read_rows
        module procedure read_rows_wp, read_rows_wp3, read_rows_i8, read_rows_i4
    end interface
    interface h5_write_attribute
        module procedure write_attr_wp, write_attr_i8, write_attr_i4, write_attr_text
    end interface
    interface h5_read_attribute
        module procedure read_attr_wp, read_attr_i8, read_attr_i4, read_attr_text
    end interface


    logical, save :: library_open = .false.

contains

    subroutine check_h5(ierr, where)
        integer, intent(in) :: ierr
        character(len=*), intent(in) :: where
        if (ierr < 0) call fatal_abort(where, 'HDF5 call failed')
    end subroutine check_h5

    subroutine library_init()
        integer :: ierr
        if (library_open) return
        call h5open_f(ierr)
        call check_h5(ierr, 'h5open_f')
        call h5eset_auto_f(0, ierr)
        library_open = .true.
    end subroutine library_init

    !> Create (truncate) a file collectively. stat /= 0 when it cannot be created.
    subroutine h5_create(env, path, file, stat)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(out) :: file
        integer, intent(out) :: stat
        integer(hid_t) :: fapl
        integer :: ierr
        call library_init()
        call h5pcreate_f(H5P_FILE_ACCESS_F, fapl, ierr)
        call check_h5(ierr, 'h5pcreate_f fapl')
        call h5pset_fapl_mpio_f(fapl, env%comm%mpi_val, MPI_INFO_NULL%mpi_val, ierr)
        call check_h5(ierr, 'h5pset_fapl_mpio_f')
        call h5fcreate_f(path, H5F_ACC_TRUNC_F, file%id, stat, access_prp=fapl)
        call h5pclose_f(fapl, ierr)
        if (stat < 0) return
        stat = 0
        call open_transfer(file)
        file%path = path
    end subroutine h5_create

    !> Open an existing file for reading collectively. stat /= 0 when it cannot be opened.
    subroutine h5_open_read(env, path, file, stat)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(out) :: file
        integer, intent(out) :: stat
        integer(hid_t) :: fapl
        integer :: ierr
        call library_init()
        call h5pcreate_f(H5P_FILE_ACCESS_F, fapl, ierr)
        call check_h5(ierr, 'h5pcreate_f fapl')
        call h5pset_fapl_mpio_f(fapl, env%comm%mpi_val, MPI_INFO_NULL%mpi_val, ierr)
        call check_h5(ierr, 'h5pset_fapl_mpio_f')
        call h5fopen_f(path, H5F_ACC_RDONLY_F, file%id, stat, access_prp=fapl)
        call h5pclose_f(fapl, ierr)
        if (stat < 0) return
        stat = 0
        call open_transfer(file)
        file%path = path
    end subroutine h5_open_read

    subroutine open_transfer(file)
        type(h5_file_t), intent(inout) :: file
        integer :: ierr
        call h5pcreate_f(H5P_DATASET_XFER_F, file%xfer, ierr)
        call check_h5(ierr, 'h5pcreate_f xfer')
        call h5pset_dxpl_mpio_f(file%xfer, H5FD_MPIO_COLLECTIVE_F, ierr)
        call check_h5(ierr, 'h5pset_dxpl_mpio_f')
    end subroutine open_transfer

    subroutine h5_close(file)
        type(h5_file_t), intent(inout) :: file
        integer :: ierr
        if (file%xfer >= 0) call h5pclose_f(file%xfer, ierr)
        if (file%id >= 0) then
            call h5fclose_f(file%id, ierr)
            call check_h5(ierr, 'h5fclose_f ' // file%path)
        end if
        file%id = -1
        file%xfer = -1
    end subroutine h5_close

    subroutine h5_group_create(file, name)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t) :: group
        integer :: ierr
        call h5gcreate_f(file%id, name, group, ierr)
        call check_h5(ierr, 'h5gcreate_f ' // name)
        call h5gclose_f(group, ierr)
    end subroutine h5_group_create

    !> Does a dataset or group exist at this path (all parents must exist)?
    logical function h5_exists(file, path)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: path
        integer :: ierr
        call h5lexists_f(file%id, path, h5_exists, ierr)
        if (ierr < 0) h5_exists = .false.
    end function h5_exists

    ! ---- row datasets -------------------------------------------------------------------

    !> File and memory dataspaces for `local` rows at `offset` of a dataset of `width` columns
    !> (width 0: one-dimensional). A rank with no rows selects nothing.
    subroutine row_spaces(dset, width, local, offset, filespace, memspace)
        integer(hid_t), intent(in) :: dset
        integer, intent(in) :: width, local
        integer(i8), intent(in) :: offset
        integer(hid_t), intent(out) :: filespace, memspace
        integer(hsize_t) :: start(2), count(2), mdims(2)
        integer :: ierr, rank
        call h5dget_space_f(dset, filespace, ierr)
        call check_h5(ierr, 'h5dget_space_f')
        rank = merge(2, 1, width > 0)
        if (local > 0) then
            if (width > 0) then
                start = [0_hsize_t, int(offset, hsize_t)]
                count = [int(width, hsize_t), int(local, hsize_t)]
            else
                start = [int(offset, hsize_t), 0_hsize_t]
                count = [int(local, hsize_t), 1_hsize_t]
            end if
            call h5sselect_hyperslab_f(filespace, H5S_SELECT_SET_F, start(1:rank), count(1:rank), &
                ierr)
            call check_h5(ierr, 'h5sselect_hyperslab_f')
            mdims = count
            call h5screate_simple_f(rank, mdims(1:rank), memspace, ierr)
        else
            call h5sselect_none_f(filespace, ierr)
            call check_h5(ierr, 'h5sselect_none_f')
            mdims = 1
            call h5screate_simple_f(rank, mdims(1:rank), memspace, ierr)
            call check_h5(ierr, 'h5screate_simple_f')
            call h5sselect_none_f(memspace, ierr)
        end if
        call check_h5(ierr, 'row memory space')
    end subroutine row_spaces

    !> Create a dataset of `total` rows (and `width` columns) and return its id and this rank's
    !> offset (collective).
    subroutine create_rows(env, file, name, file_type, width, local, dset, offset, total)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: file_type
        integer, intent(in) :: width, local
        integer(hid_t), intent(out) :: dset
        integer(i8), intent(out) :: offset, total
        integer(hsize_t) :: dims(2)
        integer(hid_t) :: space
        integer :: ierr, rank
        total = global_sum(env, int(local, i8))
        offset = exclusive_scan_i8(env, int(local, i8))
        rank = merge(2, 1, width > 0)
        if (width > 0) then
            dims = [int(width, hsize_t), int(total, hsize_t)]
        else
            dims = [int(total, hsize_t), 1_hsize_t]
        end if
        call h5screate_simple_f(rank, dims(1:rank), space, ierr)
        call check_h5(ierr, 'h5screate_simple_f ' // name)
        call h5dcreate_f(file%id, name, file_type, space, dset, ierr)
        call check_h5(ierr, 'h5dcreate_f ' // name)
        call h5sclose_f(space, ierr)
    end subroutine create_rows

    subroutine finish_rows(dset, filespace, memspace)
        integer(hid_t), intent(in) :: dset, filespace, memspace
        integer :: ierr
        call h5sclose_f(memspace, ierr)
        call h5sclose_f(filespace, ierr)
        call h5dclose_f(dset, ierr)
        call check_h5(ierr, 'h5dclose_f')
    end subroutine finish_rows

    subroutine write_rows_wp(env, file, name, values, local)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(in), target, contiguous :: values(:)
        integer, intent(in) :: local
        real(wp), target :: dummy(1)
        integer(hid_t) :: dset, filespace, memspace
        integer(i8) :: offset, total
        integer :: ierr
        call create_rows(env, file, name, H5T_NATIVE_DOUBLE, 0, local, dset, offset, total)
        if (total == 0) then
            call h5dclose_f(dset, ierr)
            return
        end if
        call row_spaces(dset, 0, local, offset, filespace, memspace)
        dummy = 0.0_wp
        if (local > 0) then
            call h5dwrite_f(dset, H5T_NATIVE_DOUBLE, c_loc(values), ierr, memspace, filespace, &
                file%xfer)
        else
            call h5dwrite_f(dset, H5T_NATIVE_DOUBLE, c_loc(dummy), ierr, memspace, filespace, &
                file%xfer)
        end if
        call check_h5(ierr, 'h5dwrite_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine write_rows_wp

    !> (3, N) in Fortran: N x 3 as h5py and ParaView see it.
    subroutine write_rows_wp3(env, file, name, values, local)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(in), target, contiguous :: values(:, :)
        integer, intent(in) :: local
        real(wp), target :: dummy(3)
        integer(hid_t) :: dset, filespace, memspace
        integer(i8) :: offset, total
        integer :: ierr
        call create_rows(env, file, name, H5T_NATIVE_DOUBLE, 3, local, dset, offset, total)
        if (total == 0) then
            call h5dclose_f(dset, ierr)
            return
        end if
        call row_spaces(dset, 3, local, offset, filespace, memspace)
        dummy = 0.0_wp
        if (local > 0) then
            call h5dwrite_f(dset, H5T_NATIVE_DOUBLE, c_loc(values), ierr, memspace, filespace, &
                file%xfer)
        else
            call h5dwrite_f(dset, H5T_NATIVE_DOUBLE, c_loc(dummy), ierr, memspace, filespace, &
                file%xfer)
        end if
        call check_h5(ierr, 'h5dwrite_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine write_rows_wp3

    subroutine write_rows_i8(env, file, name, values, local)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(in), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), target :: dummy(1)
        integer(hid_t) :: dset, filespace, memspace, mem_type
        integer(i8) :: offset, total
        integer :: ierr
        mem_type = h5kind_to_type(i8, H5_INTEGER_KIND)
        call create_rows(env, file, name, H5T_STD_I64LE, 0, local, dset, offset, total)
        if (total == 0) then
            call h5dclose_f(dset, ierr)
            return
        end if
        call row_spaces(dset, 0, local, offset, filespace, memspace)
        dummy = 0
        if (local > 0) then
            call h5dwrite_f(dset, mem_type, c_loc(values), ierr, memspace, filespace, file%xfer)
        else
            call h5dwrite_f(dset, mem_type, c_loc(dummy), ierr, memspace, filespace, file%xfer)
        end if
        call check_h5(ierr, 'h5dwrite_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine write_rows_i8

    subroutine write_rows_i4(env, file, name, values, local)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(in), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i4), target :: dummy(1)
        integer(hid_t) :: dset, filespace, memspace, mem_type
        integer(i8) :: offset, total
        integer :: ierr
        mem_type = h5kind_to_type(i4, H5_INTEGER_KIND)
        call create_rows(env, file, name, H5T_STD_I32LE, 0, local, dset, offset, total)
        if (total == 0) then
            call h5dclose_f(dset, ierr)
            return
        end if
        call row_spaces(dset, 0, local, offset, filespace, memspace)
        dummy = 0
        if (local > 0) then
            call h5dwrite_f(dset, mem_type, c_loc(values), ierr, memspace, filespace, file%xfer)
        else
            call h5dwrite_f(dset, mem_type, c_loc(dummy), ierr, memspace, filespace, file%xfer)
        end if
        call check_h5(ierr, 'h5dwrite_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine write_rows_i4

    !> Number of rows of a dataset (the last Fortran dimension); -1 when it does not exist.
    integer(i8) function h5_dataset_rows(file, name) result(rows)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t) :: dset, space
        integer(hsize_t) :: dims(2), maxdims(2)
        integer :: ierr, rank
        rows = -1
        if (.not. h5_exists(file, name)) return
        call h5dopen_f(file%id, name, dset, ierr)
        if (ierr < 0) return
        call h5dget_space_f(dset, space, ierr)
        call h5sget_simple_extent_ndims_f(space, rank, ierr)
        call h5sget_simple_extent_dims_f(space, dims(1:rank), maxdims(1:rank), ierr)
        rows = int(dims(rank), i8)
        call h5sclose_f(space, ierr)
        call h5dclose_f(dset, ierr)
    end function h5_dataset_rows

    subroutine open_rows(file, name, width, local, offset, dset, filespace, memspace)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer, intent(in) :: width, local
        integer(i8), intent(in) :: offset
        integer(hid_t), intent(out) :: dset, filespace, memspace
        integer :: ierr
        call h5dopen_f(file%id, name, dset, ierr)
        call check_h5(ierr, 'h5dopen_f ' // name)
        call row_spaces(dset, width, local, offset, filespace, memspace)
    end subroutine open_rows

    subroutine read_rows_wp(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(inout), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        real(wp), target :: dummy(1)
        integer(hid_t) :: dset, filespace, memspace
        integer :: ierr
        type(c_ptr) :: ptr
        if (h5_dataset_rows(file, name) == 0) return   ! nothing to transfer, on every rank
        call open_rows(file, name, 0, local, offset, dset, filespace, memspace)
        if (local > 0) then
            ptr = c_loc(values)
            call h5dread_f(dset, H5T_NATIVE_DOUBLE, ptr, ierr, memspace, filespace, file%xfer)
        else
            ptr = c_loc(dummy)
            call h5dread_f(dset, H5T_NATIVE_DOUBLE, ptr, ierr, memspace, filespace, file%xfer)
        end if
        call check_h5(ierr, 'h5dread_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine read_rows_wp

    subroutine read_rows_wp3(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(inout), target, contiguous :: values(:, :)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        real(wp), target :: dummy(3)
        integer(hid_t) :: dset, filespace, memspace
        integer :: ierr
        type(c_ptr) :: ptr
        if (h5_dataset_rows(file, name) == 0) return   ! nothing to transfer, on every rank
        call open_rows(file, name, 3, local, offset, dset, filespace, memspace)
        if (local > 0) then
            ptr = c_loc(values)
            call h5dread_f(dset, H5T_NATIVE_DOUBLE, ptr, ierr, memspace, filespace, file%xfer)
        else
            ptr = c_loc(dummy)
            call h5dread_f(dset, H5T_NATIVE_DOUBLE, ptr, ierr, memspace, filespace, file%xfer)
        end if
        call check_h5(ierr, 'h5dread_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine read_rows_wp3

    subroutine read_rows_i8(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(inout), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        integer(i8), target :: dummy(1)
        integer(hid_t) :: dset, filespace, memspace
        integer :: ierr
        type(c_ptr) :: ptr
        if (h5_dataset_rows(file, name) == 0) return   ! nothing to transfer, on every rank
        call open_rows(file, name, 0, local, offset, dset, filespace, memspace)
        if (local > 0) then
            ptr = c_loc(values)
            call h5dread_f(dset, h5kind_to_type(i8, H5_INTEGER_KIND), ptr, ierr, memspace, &
                filespace, file%xfer)
        else
            ptr = c_loc(dummy)
            call h5dread_f(dset, h5kind_to_type(i8, H5_INTEGER_KIND), ptr, ierr, memspace, &
                filespace, file%xfer)
        end if
        call check_h5(ierr, 'h5dread_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine read_rows_i8

    subroutine read_rows_i4(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(inout), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        integer(i4), target :: dummy(1)
        integer(hid_t) :: dset, filespace, memspace
        integer :: ierr
        type(c_ptr) :: ptr
        if (h5_dataset_rows(file, name) == 0) return   ! nothing to transfer, on every rank
        call open_rows(file, name, 0, local, offset, dset, filespace, memspace)
        if (local > 0) then
            ptr = c_loc(values)
            call h5dread_f(dset, h5kind_to_type(i4, H5_INTEGER_KIND), ptr, ierr, memspace, &
                filespace, file%xfer)
        else
            ptr = c_loc(dummy)
            call h5dread_f(dset, h5kind_to_type(i4, H5_INTEGER_KIND), ptr, ierr, memspace, &
                filespace, file%xfer)
        end if
        call check_h5(ierr, 'h5dread_f ' // name)
        call finish_rows(dset, filespace, memspace)
    end subroutine read_rows_i4

    ! ---- attributes (on the root group) ---------------------------------------------------

    subroutine scalar_attribute(file, name, file_type, attr)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: file_type
        integer(hid_t), intent(out) :: attr
        integer(hid_t) :: space
        integer :: ierr
        call h5screate_f(H5S_SCALAR_F, space, ierr)
        call check_h5(ierr, 'h5screate_f')
        call h5acreate_f(file%id, name, file_type, space, attr, ierr)
        call check_h5(ierr, 'h5acreate_f ' // name)
        call h5sclose_f(space, ierr)
    end subroutine scalar_attribute

    subroutine write_attr_wp(file, name, value)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(in), target :: value
        integer(hid_t) :: attr
        integer :: ierr
        call scalar_attribute(file, name, H5T_NATIVE_DOUBLE, attr)
        call h5awrite_f(attr, H5T_NATIVE_DOUBLE, c_loc(value), ierr)
        call check_h5(ierr, 'h5awrite_f ' // name)
        call h5aclose_f(attr, ierr)
    end subroutine write_attr_wp

    subroutine write_attr_i8(file, name, value)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(in), target :: value
        integer(hid_t) :: attr
        integer :: ierr
        call scalar_attribute(file, name, H5T_STD_I64LE, attr)
        call h5awrite_f(attr, h5kind_to_type(i8, H5_INTEGER_KIND), c_loc(value), ierr)
        call check_h5(ierr, 'h5awrite_f ' // name)
        call h5aclose_f(attr, ierr)
    end subroutine write_attr_i8

    subroutine write_attr_i4(file, name, value)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(in), target :: value
        integer(hid_t) :: attr
        integer :: ierr
        call scalar_attribute(file, name, H5T_STD_I32LE, attr)
        call h5awrite_f(attr, h5kind_to_type(i4, H5_INTEGER_KIND), c_loc(value), ierr)
        call check_h5(ierr, 'h5awrite_f ' // name)
        call h5aclose_f(attr, ierr)
    end subroutine write_attr_i4

    !> A fixed-length, null-terminated string (h5py reads it as bytes or str).
    subroutine write_attr_text(file, name, value)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name, value
        integer(hid_t) :: attr, string_type
        integer(hsize_t) :: dims(1)
        integer :: ierr
        call h5tcopy_f(H5T_C_S1, string_type, ierr)
        call check_h5(ierr, 'h5tcopy_f')
        call h5tset_size_f(string_type, int(max(len(value), 1), size_t), ierr)
        call check_h5(ierr, 'h5tset_size_f')
        call scalar_attribute(file, name, string_type, attr)
        dims = 1
        if (len(value) > 0) then
            call h5awrite_f(attr, string_type, value, dims, ierr)
        else
            call h5awrite_f(attr, string_type, ' ', dims, ierr)
        end if
        call check_h5(ierr, 'h5awrite_f ' // name)
        call h5aclose_f(attr, ierr)
        call h5tclose_f(string_type, ierr)
    end subroutine write_attr_text

    logical function h5_attribute_exists(file, name)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer :: ierr
        call h5aexists_f(file%id, name, h5_attribute_exists, ierr)
        if (ierr < 0) h5_attribute_exists = .false.
    end function h5_attribute_exists

    subroutine open_attribute(file, name, attr, stat)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(out) :: attr
        integer, intent(out) :: stat
        stat = 1
        attr = -1
        if (.not. h5_attribute_exists(file, name)) return
        call h5aopen_f(file%id, name, attr, stat)
        if (stat >= 0) stat = 0
    end subroutine open_attribute

    subroutine read_attr_wp(file, name, value, stat)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(out), target :: value
        integer, intent(out) :: stat
        integer(hid_t) :: attr
        integer :: ierr
        type(c_ptr) :: ptr
        value = 0.0_wp
        call open_attribute(file, name, attr, stat)
        if (stat /= 0) return
        ptr = c_loc(value)
        call h5aread_f(attr, H5T_NATIVE_DOUBLE, ptr, stat)
        call h5aclose_f(attr, ierr)
        if (stat >= 0) stat = 0
    end subroutine read_attr_wp

    subroutine read_attr_i8(file, name, value, stat)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(out), target :: value
        integer, intent(out) :: stat
        integer(hid_t) :: attr
        integer :: ierr
        type(c_ptr) :: ptr
        value = 0
        call open_attribute(file, name, attr, stat)
        if (stat /= 0) return
        ptr = c_loc(value)
        call h5aread_f(attr, h5kind_to_type(i8, H5_INTEGER_KIND), ptr, stat)
        call h5aclose_f(attr, ierr)
        if (stat >= 0) stat = 0
    end subroutine read_attr_i8

    subroutine read_attr_i4(file, name, value, stat)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(out), target :: value
        integer, intent(out) :: stat
        integer(hid_t) :: attr
        integer :: ierr
        type(c_ptr) :: ptr
        value = 0
        call open_attribute(file, name, attr, stat)
        if (stat /= 0) return
        ptr = c_loc(value)
        call h5aread_f(attr, h5kind_to_type(i4, H5_INTEGER_KIND), ptr, stat)
        call h5aclose_f(attr, ierr)
        if (stat >= 0) stat = 0
    end subroutine read_attr_i4

    subroutine read_attr_text(file, name, value, stat)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        character(len=:), allocatable, intent(out) :: value
        integer, intent(out) :: stat
        integer(hid_t) :: attr, file_type, mem_type
        integer(size_t) :: length
        integer(hsize_t) :: dims(1)
        integer :: ierr, k
        value = ''
        call open_attribute(file, name, attr, stat)
        if (stat /= 0) return
        call h5aget_type_f(attr, file_type, ierr)
        call h5tget_size_f(file_type, length, ierr)
        call h5tcopy_f(H5T_C_S1, mem_type, ierr)
        call h5tset_size_f(mem_type, length, ierr)
        value = repeat(" ", int(length))
        dims = 1
        call h5aread_f(attr, mem_type, value, dims, stat)
        call h5tclose_f(mem_type, ierr)
        call h5tclose_f(file_type, ierr)
        call h5aclose_f(attr, ierr)
        if (stat >= 0) stat = 0
        k = index(value, c_null_char)
        if (k > 0) value = value(1:k - 1)
    end subroutine read_attr_text

end module sph_hdf5
