!> The one parallel HDF5 wrapper (after FLEXI io_hdf5.f90 and CaNS load.f90): files opened
!> collectively on an mpi_env_t's communicator with the MPI-IO driver, row datasets written
!> and read collectively by (global rows, local rows, offset), groups, and scalar and string
!> attributes on the root or on any group or dataset.
!>
!> Rules every routine keeps:
!>  - every rank of the communicator makes every call, also a rank with no rows (it selects
!>    nothing with h5sselect_none and still takes part in the collective transfer);
!>  - every HDF5 return code is checked; a failure inside an open file (a write or read that
!>    fails) is an I/O-system or programming error that one rank may hit alone, so check_h5
!>    prints HDF5's error stack and calls fatal_abort. Opening/creating a file, closing it and
!>    reading attributes instead return stat/errmsg when the caller asks for them (stdlib
!>    state convention) and stop through sph_errors otherwise;
!>  - attributes are metadata: every rank must write the same value (HDF5 requirement).
!>
!> Shapes: a Fortran array (3, N) is stored with dimensions (3, N) in Fortran order, which
!> h5py and ParaView (C order) see as N x 3; a row is always the last Fortran dimension.
!>
!> Datatypes matching sph_kinds (the one place they are chosen): real(wp) is stored as
!> H5T_IEEE_F64LE (what H5T_NATIVE_DOUBLE is on every platform we run on, spelled out so a
!> file does not depend on the writing machine), integer(i8) as H5T_STD_I64LE and
!> integer(i4) as H5T_STD_I32LE; memory types come from h5kind_to_type on the sph_kinds kinds.
!> Strings are written as variable-length UTF-8 strings (h5py reads them as str, and a long
!> text such as the resolved input lives in the global heap instead of the 64 KiB-limited
!> object header); the reader accepts fixed-length strings too.
!>
!> The HDF5 library is opened (h5open_f) when the first file is opened and closed
!> (h5close_f) when the last one is closed: a reference count of open files, the only module
!> state here.
module sph_hdf5
    use, intrinsic :: iso_c_binding, only: c_loc, c_ptr, c_char, c_null_char, c_size_t, &
        c_f_pointer, c_associated, c_null_ptr
    use hdf5
    use mpi_f08, only: MPI_INFO_NULL
    use sph_kinds, only: wp, i4, i8
    use sph_errors, only: fatal_abort, STATUS_OUTPUT_FAILED
    use sph_mpi_env, only: mpi_env_t, global_sum, exclusive_scan_i8, rank0_flag
    use sph_filesystem, only: MAX_FILE_PATH, disk_hint
    use sph_logger, only: int_text
    implicit none
    private
    public :: h5_file_t, h5_create, h5_open_read, h5_close, check_h5
    public :: h5_group_create, h5_exists, h5_row_layout
    public :: h5_write_rows, h5_read_rows, h5_dataset_rows
    public :: h5_write_attribute, h5_read_attribute, h5_attribute_exists

    !> An open file and the collective transfer property list used for its datasets.
    type :: h5_file_t
        integer(hid_t) :: id = -1
        integer(hid_t) :: xfer = -1
        character(len=:), allocatable :: path
    end type h5_file_t

    !> Collective row writers: (env, file, name, values, local [, offset, total]).
    interface h5_write_rows
        module procedure write_rows_wp, write_rows_wpn, write_rows_i8, write_rows_i4
    end interface
    !> Collective row readers: (file, name, values, local, offset).
    interface h5_read_rows
        module procedure read_rows_wp, read_rows_wpn, read_rows_i8, read_rows_i4
    end interface
    !> (file, name, value [, at]); `at` is the object (group or dataset) path, default root.
    interface h5_write_attribute
        module procedure write_attr_wp, write_attr_i8, write_attr_i4, write_attr_text
    end interface
    !> (file, name, value [, stat, errmsg, at]).
    interface h5_read_attribute
        module procedure read_attr_wp, read_attr_i8, read_attr_i4, read_attr_text
    end interface

    interface
        pure integer(c_size_t) function c_strlen(s) bind(C, name="strlen")
            import :: c_ptr, c_size_t
            type(c_ptr), value :: s
        end function c_strlen
    end interface

    integer, save :: open_files = 0  !< files open through this module; HDF5 is open while > 0

contains

    ! ---- errors, library, datatypes -------------------------------------------------------

    !> Every HDF5 return code goes through here: a negative code prints HDF5's error stack
    !> and aborts, naming the call (and object) in `where`.
    subroutine check_h5(ierr, where)
        integer, intent(in) :: ierr
        character(len=*), intent(in) :: where
        character(len=16) :: code
        integer :: ierr2
        if (ierr >= 0) return
        call h5eprint_f(ierr2)
        write(code, '(i0)') ierr
        call fatal_abort(where, 'HDF5 call failed (return code ' // trim(code) // ')')
    end subroutine check_h5

    !> check_h5 for a call that writes to the file `path`: a failure stops with
    !> STATUS_OUTPUT_FAILED, and where the file system is (nearly) full it says so instead
    !> of printing HDF5's error stack (which gives no reason).
    subroutine check_write(ierr, where, path)
        integer, intent(in) :: ierr
        character(len=*), intent(in) :: where, path
        character(len=16) :: code
        character(len=:), allocatable :: hint
        integer :: ierr2
        if (ierr >= 0) return
        hint = disk_hint(path)
        if (len(hint) == 0) call h5eprint_f(ierr2)
        write(code, '(i0)') ierr
        call fatal_abort(where, "writing '" // path // "' failed (HDF5 return code " // &
            trim(code) // ')' // hint, STATUS_OUTPUT_FAILED)
    end subroutine check_write

    subroutine library_acquire()
        integer :: ierr
        if (open_files == 0) then
            call h5open_f(ierr)
            call check_h5(ierr, 'sph_hdf5: h5open_f')
            ! expected failures (probing a missing file) must not flood stderr; check_h5
            ! prints the stack itself on unexpected ones
            call h5eset_auto_f(0, ierr)
            call check_h5(ierr, 'sph_hdf5: h5eset_auto_f')
        end if
        open_files = open_files + 1
    end subroutine library_acquire

    subroutine library_release()
        integer :: ierr
        open_files = open_files - 1
        if (open_files == 0) then
            call h5close_f(ierr)
            call check_h5(ierr, 'sph_hdf5: h5close_f')
        end if
    end subroutine library_release

    integer(hid_t) function mem_type_wp()
        mem_type_wp = h5kind_to_type(wp, H5_REAL_KIND)
    end function mem_type_wp

    integer(hid_t) function mem_type_i8()
        mem_type_i8 = h5kind_to_type(i8, H5_INTEGER_KIND)
    end function mem_type_i8

    integer(hid_t) function mem_type_i4()
        mem_type_i4 = h5kind_to_type(i4, H5_INTEGER_KIND)
    end function mem_type_i4

    !> Hand a status to the caller, or stop (fatal_abort) on a failure it did not ask about.
    !> The public routine sets errmsg itself: gfortran 12 loses the length of an optional
    !> deferred-length character dummy passed on to another optional dummy, so errmsg is
    !> never passed down.
    subroutine hand_over(status, where, message, stat)
        integer, intent(in) :: status
        character(len=*), intent(in) :: where, message
        integer, intent(out), optional :: stat
        if (present(stat)) then
            stat = status
        else if (status /= 0) then
            call fatal_abort(where, message)
        end if
    end subroutine hand_over

    ! ---- files and groups ----------------------------------------------------------------

    !> Create (truncate) `path` collectively on env%comm. Failure: stat /= 0 and errmsg, or a
    !> stop when stat is absent.
    subroutine h5_create(env, path, file, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(out) :: file
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        integer :: status
        character(len=:), allocatable :: message
        call open_file(env, path, .true., file, status, message)
        call hand_over(status, 'h5_create', message, stat)
        if (present(errmsg)) errmsg = message
    end subroutine h5_create

    !> Open an existing `path` read-only, collectively on env%comm.
    subroutine h5_open_read(env, path, file, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(out) :: file
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        integer :: status
        character(len=:), allocatable :: message
        call open_file(env, path, .false., file, status, message)
        call hand_over(status, 'h5_open_read', message, stat)
        if (present(errmsg)) errmsg = message
    end subroutine h5_open_read

    subroutine open_file(env, path, create, file, stat, message)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        logical, intent(in) :: create
        type(h5_file_t), intent(inout) :: file
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: message
        integer(hid_t) :: fapl
        integer :: ierr, status
        logical :: is_directory
        stat = 0
        message = ''
        ! refused here, before the library aborts the process on a long name or prints a
        ! page of read errors for a directory
        if (len(path) > MAX_FILE_PATH) then
            stat = 1
            message = "the path '" // path // "' is " // int_text(int(len(path), i8)) // &
                ' characters long: HDF5 over MPI-IO takes at most ' // &
                int_text(int(MAX_FILE_PATH, i8)) // ' (a shorter folder, or a symbolic link)'
            return
        end if
        ! rank 0 asks and every rank takes its answer: a rank that saw a folder where the
        ! others did not (another working folder, a network file system's cache) returned
        ! here while they waited in the collective open (fz51: a hang, no message)
        is_directory = .false.
        if (env%rank == 0) inquire(file=path // '/.', exist=is_directory)
        is_directory = rank0_flag(env, is_directory)
        if (is_directory) then
            stat = 1
            message = "'" // path // "' is a directory, not an HDF5 file"
            return
        end if
        call library_acquire()
        call h5pcreate_f(H5P_FILE_ACCESS_F, fapl, ierr)
        call check_h5(ierr, 'sph_hdf5: h5pcreate_f (file access)')
        call h5pset_fapl_mpio_f(fapl, env%comm%mpi_val, MPI_INFO_NULL%mpi_val, ierr)
        call check_h5(ierr, 'sph_hdf5: h5pset_fapl_mpio_f')
        if (create) then
            call h5fcreate_f(path, H5F_ACC_TRUNC_F, file%id, status, access_prp=fapl)
        else
            call h5fopen_f(path, H5F_ACC_RDONLY_F, file%id, status, access_prp=fapl)
        end if
        call h5pclose_f(fapl, ierr)
        call check_h5(ierr, 'sph_hdf5: h5pclose_f (file access)')
        if (status < 0) then
            file%id = -1
            call library_release()
            stat = 1
            if (create) then
                message = "cannot create the HDF5 file '" // path // "'"
            else
                message = "cannot open '" // path // &
                    "' as an HDF5 file (missing, unreadable or truncated)"
            end if
            return
        end if
        file%path = path
        call h5pcreate_f(H5P_DATASET_XFER_F, file%xfer, ierr)
        call check_h5(ierr, 'sph_hdf5: h5pcreate_f (transfer) ' // path)
        call h5pset_dxpl_mpio_f(file%xfer, H5FD_MPIO_COLLECTIVE_F, ierr)
        call check_h5(ierr, 'sph_hdf5: h5pset_dxpl_mpio_f ' // path)
    end subroutine open_file

    !> Close collectively. Failure (data may not have reached the disk): stat /= 0, or a stop.
    subroutine h5_close(file, stat, errmsg)
        type(h5_file_t), intent(inout) :: file
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        integer :: ierr
        if (present(stat)) stat = 0
        if (present(errmsg)) errmsg = ''
        if (file%id < 0) return
        if (file%xfer >= 0) then
            call h5pclose_f(file%xfer, ierr)
            call check_h5(ierr, 'sph_hdf5: h5pclose_f (transfer) ' // file%path)
        end if
        call h5fclose_f(file%id, ierr)
        file%id = -1
        file%xfer = -1
        call library_release()
        if (ierr < 0) then
            call hand_over(1, 'h5_close', "closing '" // file%path // "' failed", stat)
            if (present(errmsg)) errmsg = "closing '" // file%path // "' failed"
        end if
    end subroutine h5_close

    !> Create a group (its parent must exist), collectively.
    subroutine h5_group_create(file, name)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t) :: group
        integer :: ierr
        call h5gcreate_f(file%id, name, group, ierr)
        call check_h5(ierr, 'sph_hdf5: h5gcreate_f ' // name // ' in ' // file%path)
        call h5gclose_f(group, ierr)
        call check_h5(ierr, 'sph_hdf5: h5gclose_f ' // name)
    end subroutine h5_group_create

    !> Does a group or dataset exist at this path (missing parents: false)?
    logical function h5_exists(file, path)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: path
        integer :: ierr, k
        logical :: found
        h5_exists = .false.
        if (file%id < 0) return
        ! h5lexists_f fails rather than answering false when a parent is missing: walk down
        do k = 2, len(path) + 1
            if (k <= len(path)) then
                if (path(k:k) /= '/') cycle
            end if
            call h5lexists_f(file%id, path(1:k - 1), found, ierr)
            if (ierr < 0 .or. .not. found) return
        end do
        h5_exists = .true.
    end function h5_exists

    ! ---- row datasets ---------------------------------------------------------------------

    !> This rank's offset and the global row count for `local` rows per rank (collective:
    !> MPI_Exscan and MPI_Allreduce). Compute once per file and pass to every h5_write_rows.
    subroutine h5_row_layout(env, local, offset, total)
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: local
        integer(i8), intent(out) :: offset, total
        offset = exclusive_scan_i8(env, int(local, i8))
        total = global_sum(env, int(local, i8))
    end subroutine h5_row_layout

    !> Create dataset `name` of `total` rows (`width` columns; 0: one-dimensional) and write
    !> this rank's `local` rows at `offset` from `buffer`, collectively.
    subroutine write_rows(env, file, name, file_type, mem_type, width, local, buffer, &
                          offset, total)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: file_type, mem_type
        integer, intent(in) :: width, local
        type(c_ptr), intent(in) :: buffer
        integer(i8), intent(in), optional :: offset, total
        integer(i8) :: my_offset, my_total
        integer(hsize_t) :: dims(2)
        integer(hid_t) :: space, dset, filespace, memspace
        integer :: ierr, rank
        character(len=:), allocatable :: where
        where = 'h5_write_rows ' // name // ' in ' // file%path
        if (present(offset) .neqv. present(total)) then
            call fatal_abort(where, 'give both offset and total, or neither')
        end if
        if (present(offset)) then
            my_offset = offset
            my_total = total
        else
            call h5_row_layout(env, local, my_offset, my_total)
        end if
        if (local < 0 .or. my_offset < 0 .or. my_offset + local > my_total) then
            call fatal_abort(where, 'rows outside the dataset (local, offset, total)')
        end if
        rank = merge(2, 1, width > 0)
        if (width > 0) then
            dims = [int(width, hsize_t), int(my_total, hsize_t)]
        else
            dims = [int(my_total, hsize_t), 1_hsize_t]
        end if
        call h5screate_simple_f(rank, dims(1:rank), space, ierr)
        call check_h5(ierr, where // ': h5screate_simple_f')
        call h5dcreate_f(file%id, name, file_type, space, dset, ierr)
        call check_write(ierr, where // ': h5dcreate_f', file%path)
        call h5sclose_f(space, ierr)
        call check_h5(ierr, where // ': h5sclose_f')
        if (my_total > 0) then  ! same decision on every rank
            call row_spaces(dset, width, local, my_offset, where, filespace, memspace)
            call h5dwrite_f(dset, mem_type, buffer, ierr, memspace, filespace, file%xfer)
            call check_write(ierr, where // ': h5dwrite_f', file%path)
            call close_spaces(filespace, memspace, where)
        end if
        call h5dclose_f(dset, ierr)
        call check_write(ierr, where // ': h5dclose_f', file%path)
    end subroutine write_rows

    !> File and memory dataspaces for `local` rows at `offset` of a dataset of `width`
    !> columns (0: one-dimensional). A rank with no rows selects nothing in both.
    subroutine row_spaces(dset, width, local, offset, where, filespace, memspace)
        integer(hid_t), intent(in) :: dset
        integer, intent(in) :: width, local
        integer(i8), intent(in) :: offset
        character(len=*), intent(in) :: where
        integer(hid_t), intent(out) :: filespace, memspace
        integer(hsize_t) :: start(2), count(2)
        integer :: ierr, rank
        call h5dget_space_f(dset, filespace, ierr)
        call check_h5(ierr, where // ': h5dget_space_f')
        rank = merge(2, 1, width > 0)
        if (width > 0) then
            start = [0_hsize_t, int(offset, hsize_t)]
            count = [int(width, hsize_t), int(max(local, 1), hsize_t)]
        else
            start = [int(offset, hsize_t), 0_hsize_t]
            count = [int(max(local, 1), hsize_t), 1_hsize_t]
        end if
        call h5screate_simple_f(rank, count(1:rank), memspace, ierr)
        call check_h5(ierr, where // ': h5screate_simple_f (memory)')
        if (local > 0) then
            call h5sselect_hyperslab_f(filespace, H5S_SELECT_SET_F, start(1:rank), &
                count(1:rank), ierr)
            call check_h5(ierr, where // ': h5sselect_hyperslab_f')
        else
            call h5sselect_none_f(filespace, ierr)
            call check_h5(ierr, where // ': h5sselect_none_f (file)')
            call h5sselect_none_f(memspace, ierr)
            call check_h5(ierr, where // ': h5sselect_none_f (memory)')
        end if
    end subroutine row_spaces

    subroutine close_spaces(filespace, memspace, where)
        integer(hid_t), intent(in) :: filespace, memspace
        character(len=*), intent(in) :: where
        integer :: ierr
        call h5sclose_f(memspace, ierr)
        call check_h5(ierr, where // ': h5sclose_f (memory)')
        call h5sclose_f(filespace, ierr)
        call check_h5(ierr, where // ': h5sclose_f (file)')
    end subroutine close_spaces

    subroutine check_capacity(name, have, need)
        character(len=*), intent(in) :: name
        integer, intent(in) :: have, need
        if (have < need) call fatal_abort('sph_hdf5 ' // name, &
            'the array holds fewer values than the rows to transfer')
    end subroutine check_capacity

    !> real(wp) rows: an N-row one-dimensional dataset.
    subroutine write_rows_wp(env, file, name, values, local, offset, total)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(in), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in), optional :: offset, total
        real(wp), target :: dummy(1)
        type(c_ptr) :: buffer
        dummy = 0.0_wp
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values), local)
            buffer = c_loc(values)
        end if
        call write_rows(env, file, name, H5T_IEEE_F64LE, mem_type_wp(), 0, local, buffer, &
            offset, total)
    end subroutine write_rows_wp

    !> real(wp) (w, N) in Fortran: N x w as h5py and ParaView see it.
    subroutine write_rows_wpn(env, file, name, values, local, offset, total)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(in), target, contiguous :: values(:, :)
        integer, intent(in) :: local
        integer(i8), intent(in), optional :: offset, total
        real(wp), target :: dummy(size(values, 1))
        type(c_ptr) :: buffer
        dummy = 0.0_wp
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values, 2), local)
            buffer = c_loc(values)
        end if
        call write_rows(env, file, name, H5T_IEEE_F64LE, mem_type_wp(), size(values, 1), &
            local, buffer, offset, total)
    end subroutine write_rows_wpn

    subroutine write_rows_i8(env, file, name, values, local, offset, total)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(in), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in), optional :: offset, total
        integer(i8), target :: dummy(1)
        type(c_ptr) :: buffer
        dummy = 0
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values), local)
            buffer = c_loc(values)
        end if
        call write_rows(env, file, name, H5T_STD_I64LE, mem_type_i8(), 0, local, buffer, &
            offset, total)
    end subroutine write_rows_i8

    !> integer(i4) (the default integer): stored as int32.
    subroutine write_rows_i4(env, file, name, values, local, offset, total)
        type(mpi_env_t), intent(in) :: env
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(in), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in), optional :: offset, total
        integer(i4), target :: dummy(1)
        type(c_ptr) :: buffer
        dummy = 0
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values), local)
            buffer = c_loc(values)
        end if
        call write_rows(env, file, name, H5T_STD_I32LE, mem_type_i4(), 0, local, buffer, &
            offset, total)
    end subroutine write_rows_i4

    !> Rows of a dataset (its last Fortran dimension, h5py's first); -1 when it does not
    !> exist. `width`: 0 for a one-dimensional dataset, else the columns (h5py's 2nd size).
    integer(i8) function h5_dataset_rows(file, name, width, floats) result(rows)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer, intent(out), optional :: width
        !> whether it stores floating-point values (an integer field's dataset must not: HDF5
        !> would round them, and a NaN traps where floating-point exceptions do)
        logical, intent(out), optional :: floats
        integer(hid_t) :: dset, space, file_type
        integer(hsize_t) :: dims(2), maxdims(2)
        integer :: ierr, rank, class
        rows = -1
        if (present(width)) width = -1
        if (present(floats)) floats = .false.
        if (.not. h5_exists(file, name)) return
        call h5dopen_f(file%id, name, dset, ierr)
        if (ierr < 0) return   ! a group of that name
        call h5dget_space_f(dset, space, ierr)
        call check_h5(ierr, 'h5_dataset_rows: h5dget_space_f ' // name)
        call h5sget_simple_extent_ndims_f(space, rank, ierr)
        call check_h5(ierr, 'h5_dataset_rows: h5sget_simple_extent_ndims_f ' // name)
        if (rank == 1 .or. rank == 2) then
            call h5sget_simple_extent_dims_f(space, dims(1:rank), maxdims(1:rank), ierr)
            call check_h5(ierr, 'h5_dataset_rows: h5sget_simple_extent_dims_f ' // name)
            rows = int(dims(rank), i8)
            if (present(width)) width = merge(int(dims(1)), 0, rank == 2)
        end if
        call h5sclose_f(space, ierr)
        call check_h5(ierr, 'h5_dataset_rows: h5sclose_f ' // name)
        if (present(floats)) then
            call h5dget_type_f(dset, file_type, ierr)
            call check_h5(ierr, 'h5_dataset_rows: h5dget_type_f ' // name)
            call h5tget_class_f(file_type, class, ierr)
            call check_h5(ierr, 'h5_dataset_rows: h5tget_class_f ' // name)
            floats = class == H5T_FLOAT_F
            call h5tclose_f(file_type, ierr)
            call check_h5(ierr, 'h5_dataset_rows: h5tclose_f ' // name)
        end if
        call h5dclose_f(dset, ierr)
        call check_h5(ierr, 'h5_dataset_rows: h5dclose_f ' // name)
    end function h5_dataset_rows

    !> Read this rank's `local` rows from `offset` (0-based) of dataset `name`, collectively;
    !> a rank with no rows takes part selecting nothing. The dataset must exist with that
    !> width and hold the rows (check with h5_dataset_rows first to get a status instead).
    subroutine read_rows(file, name, mem_type, width, local, offset, buffer)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: mem_type
        integer, intent(in) :: width, local
        integer(i8), intent(in) :: offset
        type(c_ptr), intent(in) :: buffer
        integer(hid_t) :: dset, filespace, memspace
        integer(i8) :: rows
        integer :: ierr, file_width
        type(c_ptr) :: target_buffer   ! h5dread_f wants a variable
        character(len=:), allocatable :: where
        where = 'h5_read_rows ' // name // ' in ' // file%path
        target_buffer = buffer
        rows = h5_dataset_rows(file, name, file_width)
        if (rows < 0) call fatal_abort(where, 'no such dataset')
        if (file_width /= width) call fatal_abort(where, 'the dataset has another shape')
        if (local < 0 .or. offset < 0 .or. offset + local > rows) then
            call fatal_abort(where, 'rows outside the dataset (local, offset)')
        end if
        if (rows == 0) return   ! nothing to transfer, the same on every rank
        call h5dopen_f(file%id, name, dset, ierr)
        call check_h5(ierr, where // ': h5dopen_f')
        call row_spaces(dset, width, local, offset, where, filespace, memspace)
        call h5dread_f(dset, mem_type, target_buffer, ierr, memspace, filespace, file%xfer)
        call check_h5(ierr, where // ': h5dread_f')
        call close_spaces(filespace, memspace, where)
        call h5dclose_f(dset, ierr)
        call check_h5(ierr, where // ': h5dclose_f')
    end subroutine read_rows

    subroutine read_rows_wp(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(inout), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        real(wp), target :: dummy(1)
        type(c_ptr) :: buffer
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values), local)
            buffer = c_loc(values)
        end if
        call read_rows(file, name, mem_type_wp(), 0, local, offset, buffer)
    end subroutine read_rows_wp

    !> real(wp) (w, N) rows of an N x w dataset.
    subroutine read_rows_wpn(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(inout), target, contiguous :: values(:, :)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        real(wp), target :: dummy(size(values, 1))
        type(c_ptr) :: buffer
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values, 2), local)
            buffer = c_loc(values)
        end if
        call read_rows(file, name, mem_type_wp(), size(values, 1), local, offset, buffer)
    end subroutine read_rows_wpn

    subroutine read_rows_i8(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(inout), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        integer(i8), target :: dummy(1)
        type(c_ptr) :: buffer
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values), local)
            buffer = c_loc(values)
        end if
        call read_rows(file, name, mem_type_i8(), 0, local, offset, buffer)
    end subroutine read_rows_i8

    subroutine read_rows_i4(file, name, values, local, offset)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(inout), target, contiguous :: values(:)
        integer, intent(in) :: local
        integer(i8), intent(in) :: offset
        integer(i4), target :: dummy(1)
        type(c_ptr) :: buffer
        buffer = c_loc(dummy)
        if (local > 0) then
            call check_capacity(name, size(values), local)
            buffer = c_loc(values)
        end if
        call read_rows(file, name, mem_type_i4(), 0, local, offset, buffer)
    end subroutine read_rows_i4

    ! ---- attributes -----------------------------------------------------------------------

    !> The object an attribute hangs on: `at` or the root group.
    function object_path(at) result(path)
        character(len=*), intent(in), optional :: at
        character(len=:), allocatable :: path
        path = '/'
        if (present(at)) then
            if (len_trim(at) > 0) path = trim(at)
        end if
    end function object_path

    !> Whether the attribute `name` exists on the file's root group or on the object `at`.
    logical function h5_attribute_exists(file, name, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        character(len=*), intent(in), optional :: at
        integer :: ierr
        h5_attribute_exists = .false.
        if (present(at)) then
            if (.not. h5_exists(file, object_path(at))) return
        end if
        call h5aexists_by_name_f(file%id, object_path(at), name, h5_attribute_exists, ierr)
        if (ierr < 0) h5_attribute_exists = .false.
    end function h5_attribute_exists

    !> A new scalar attribute (an existing one of that name is replaced), collectively.
    subroutine create_attribute(file, name, file_type, at, attr)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: file_type
        character(len=*), intent(in), optional :: at
        integer(hid_t), intent(out) :: attr
        integer(hid_t) :: space
        integer :: ierr
        character(len=:), allocatable :: where
        where = 'h5_write_attribute ' // name // ' on ' // object_path(at) // ' in ' // file%path
        if (h5_attribute_exists(file, name, at)) then
            call h5adelete_by_name_f(file%id, object_path(at), name, ierr)
            call check_h5(ierr, where // ': h5adelete_by_name_f')
        end if
        call h5screate_f(H5S_SCALAR_F, space, ierr)
        call check_h5(ierr, where // ': h5screate_f')
        call h5acreate_by_name_f(file%id, object_path(at), name, file_type, space, attr, ierr)
        call check_h5(ierr, where // ': h5acreate_by_name_f')
        call h5sclose_f(space, ierr)
        call check_h5(ierr, where // ': h5sclose_f')
    end subroutine create_attribute

    subroutine write_scalar(file, name, file_type, mem_type, buffer, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: file_type, mem_type
        type(c_ptr), intent(in) :: buffer
        character(len=*), intent(in), optional :: at
        integer(hid_t) :: attr
        integer :: ierr
        call create_attribute(file, name, file_type, at, attr)
        call h5awrite_f(attr, mem_type, buffer, ierr)
        call check_write(ierr, 'h5_write_attribute ' // name // ': h5awrite_f', file%path)
        call h5aclose_f(attr, ierr)
        call check_h5(ierr, 'h5_write_attribute ' // name // ': h5aclose_f')
    end subroutine write_scalar

    !> float64 scalar attribute.
    subroutine write_attr_wp(file, name, value, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(in) :: value
        character(len=*), intent(in), optional :: at
        real(wp), target :: copy
        copy = value
        call write_scalar(file, name, H5T_IEEE_F64LE, mem_type_wp(), c_loc(copy), at)
    end subroutine write_attr_wp

    !> int64 scalar attribute.
    subroutine write_attr_i8(file, name, value, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(in) :: value
        character(len=*), intent(in), optional :: at
        integer(i8), target :: copy
        copy = value
        call write_scalar(file, name, H5T_STD_I64LE, mem_type_i8(), c_loc(copy), at)
    end subroutine write_attr_i8

    !> int32 scalar attribute.
    subroutine write_attr_i4(file, name, value, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(in) :: value
        character(len=*), intent(in), optional :: at
        integer(i4), target :: copy
        copy = value
        call write_scalar(file, name, H5T_STD_I32LE, mem_type_i4(), c_loc(copy), at)
    end subroutine write_attr_i4

    !> Variable-length UTF-8 string attribute, any length (it lives in the global heap).
    subroutine write_attr_text(file, name, value, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name, value
        character(len=*), intent(in), optional :: at
        character(kind=c_char), allocatable, target :: chars(:)
        type(c_ptr), target :: string
        integer(hid_t) :: string_type
        integer :: ierr, k
        allocate(chars(len(value) + 1))
        do k = 1, len(value)
            chars(k) = value(k:k)
        end do
        chars(len(value) + 1) = c_null_char
        string = c_loc(chars)
        call variable_string_type(H5T_CSET_UTF8_F, string_type)
        call write_scalar(file, name, string_type, string_type, c_loc(string), at)
        call h5tclose_f(string_type, ierr)
        call check_h5(ierr, 'h5_write_attribute ' // name // ': h5tclose_f')
    end subroutine write_attr_text

    subroutine variable_string_type(cset, string_type)
        integer, intent(in) :: cset
        integer(hid_t), intent(out) :: string_type
        integer :: ierr
        call h5tcopy_f(H5T_STRING, string_type, ierr)   ! H5T_STRING: variable-length C string
        call check_h5(ierr, 'sph_hdf5: h5tcopy_f (string)')
        call h5tset_cset_f(string_type, cset, ierr)
        call check_h5(ierr, 'sph_hdf5: h5tset_cset_f')
    end subroutine variable_string_type

    !> Open attribute `name` for reading; stat /= 0 with a message when it is missing.
    subroutine open_attribute(file, name, at, attr, stat, message)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        character(len=*), intent(in), optional :: at
        integer(hid_t), intent(out) :: attr
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: message
        stat = 0
        message = ''
        attr = -1
        if (.not. h5_attribute_exists(file, name, at)) then
            stat = 1
            message = "'" // file%path // "' has no attribute '" // name // "' on " // &
                object_path(at)
            return
        end if
        call h5aopen_by_name_f(file%id, object_path(at), name, attr, stat)
        if (stat < 0) then
            stat = 1
            message = "cannot open the attribute '" // name // "' of '" // file%path // "'"
        end if
    end subroutine open_attribute

    subroutine read_scalar(file, name, mem_type, buffer, at, status, message)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(hid_t), intent(in) :: mem_type
        type(c_ptr), intent(in) :: buffer
        character(len=*), intent(in), optional :: at
        integer, intent(out) :: status
        character(len=:), allocatable, intent(out) :: message
        integer(hid_t) :: attr, file_type
        integer :: ierr, file_class, mem_class
        type(c_ptr) :: target_buffer   ! h5aread_f wants a variable
        target_buffer = buffer
        call open_attribute(file, name, at, attr, status, message)
        if (status == 0) then
            ! a floating-point value is not converted to an integer: HDF5 would round or
            ! clip it, and a NaN traps where floating-point exceptions do (debug builds)
            call h5aget_type_f(attr, file_type, ierr)
            call check_h5(ierr, 'h5_read_attribute ' // name // ': h5aget_type_f')
            call h5tget_class_f(file_type, file_class, ierr)
            call check_h5(ierr, 'h5_read_attribute ' // name // ': h5tget_class_f')
            call h5tclose_f(file_type, ierr)
            call check_h5(ierr, 'h5_read_attribute ' // name // ': h5tclose_f')
            call h5tget_class_f(mem_type, mem_class, ierr)
            call check_h5(ierr, 'h5_read_attribute ' // name // ': h5tget_class_f')
            if (mem_class == H5T_INTEGER_F .and. file_class == H5T_FLOAT_F) then
                call h5aclose_f(attr, ierr)
                call check_h5(ierr, 'h5_read_attribute ' // name // ': h5aclose_f')
                status = 1
                message = "the attribute '" // name // "' of '" // file%path // &
                    "' holds a floating-point value where an integer belongs"
                return
            end if
            call h5aread_f(attr, mem_type, target_buffer, status)
            call h5aclose_f(attr, ierr)
            call check_h5(ierr, 'h5_read_attribute ' // name // ': h5aclose_f')
            if (status < 0) then
                status = 1
                message = "cannot read the attribute '" // name // "' of '" // file%path // &
                    "' as a number"
            end if
        end if
    end subroutine read_scalar

    subroutine read_attr_wp(file, name, value, stat, errmsg, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        real(wp), intent(out), target :: value
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        character(len=*), intent(in), optional :: at
        integer :: status
        character(len=:), allocatable :: message
        value = 0.0_wp
        call read_scalar(file, name, mem_type_wp(), c_loc(value), at, status, message)
        call hand_over(status, 'h5_read_attribute', message, stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_attr_wp

    subroutine read_attr_i8(file, name, value, stat, errmsg, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i8), intent(out), target :: value
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        character(len=*), intent(in), optional :: at
        integer :: status
        character(len=:), allocatable :: message
        value = 0
        call read_scalar(file, name, mem_type_i8(), c_loc(value), at, status, message)
        call hand_over(status, 'h5_read_attribute', message, stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_attr_i8

    subroutine read_attr_i4(file, name, value, stat, errmsg, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        integer(i4), intent(out), target :: value
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        character(len=*), intent(in), optional :: at
        integer :: status
        character(len=:), allocatable :: message
        value = 0
        call read_scalar(file, name, mem_type_i4(), c_loc(value), at, status, message)
        call hand_over(status, 'h5_read_attribute', message, stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_attr_i4

    !> A string attribute, variable- or fixed-length; a fixed-length one ends at its first
    !> NUL (trailing blanks of a space-padded one are removed).
    subroutine read_attr_text(file, name, value, stat, errmsg, at)
        type(h5_file_t), intent(in) :: file
        character(len=*), intent(in) :: name
        character(len=:), allocatable, intent(out) :: value
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        character(len=*), intent(in), optional :: at
        integer(hid_t) :: attr, file_type, mem_type, space
        integer(size_t) :: length
        integer :: status, ierr, class, cset, pad, k, n
        logical :: variable
        type(c_ptr), target :: string
        type(c_ptr) :: buffer
        character(kind=c_char), pointer :: heap(:)
        character(kind=c_char), allocatable, target :: chars(:)
        character(len=:), allocatable :: message, where
        value = ''
        where = 'h5_read_attribute ' // name // ' in ' // file%path
        call open_attribute(file, name, at, attr, status, message)
        if (status /= 0) then
            call hand_over(status, 'h5_read_attribute', message, stat)
            if (present(errmsg)) errmsg = message
            return
        end if
        call h5aget_type_f(attr, file_type, ierr)
        call check_h5(ierr, where // ': h5aget_type_f')
        call h5tget_class_f(file_type, class, ierr)
        call check_h5(ierr, where // ': h5tget_class_f')
        if (class /= H5T_STRING_F) then
            call h5tclose_f(file_type, ierr)
            call h5aclose_f(attr, ierr)
            message = "the attribute '" // name // "' of '" // file%path // "' is not a string"
            call hand_over(1, 'h5_read_attribute', message, stat)
            if (present(errmsg)) errmsg = message
            return
        end if
        call h5tis_variable_str_f(file_type, variable, ierr)
        call check_h5(ierr, where // ': h5tis_variable_str_f')
        call h5tget_cset_f(file_type, cset, ierr)
        call check_h5(ierr, where // ': h5tget_cset_f')
        if (variable) then
            call variable_string_type(cset, mem_type)
            string = c_null_ptr
            buffer = c_loc(string)
            call h5aread_f(attr, mem_type, buffer, status)
            if (status >= 0 .and. c_associated(string)) then
                n = int(c_strlen(string))
                call c_f_pointer(string, heap, [n])
                value = repeat(' ', n)
                do k = 1, n
                    value(k:k) = heap(k)
                end do
                ! give HDF5 back the string it allocated
                call h5screate_f(H5S_SCALAR_F, space, ierr)
                call check_h5(ierr, where // ': h5screate_f')
                call h5dvlen_reclaim_f(mem_type, space, H5P_DEFAULT_F, buffer, ierr)
                call check_h5(ierr, where // ': h5dvlen_reclaim_f')
                call h5sclose_f(space, ierr)
            end if
        else
            call h5tget_size_f(file_type, length, ierr)
            call check_h5(ierr, where // ': h5tget_size_f')
            call h5tget_strpad_f(file_type, pad, ierr)
            call check_h5(ierr, where // ': h5tget_strpad_f')
            call h5tcopy_f(H5T_C_S1, mem_type, ierr)
            call check_h5(ierr, where // ': h5tcopy_f')
            call h5tset_size_f(mem_type, length, ierr)
            call check_h5(ierr, where // ': h5tset_size_f')
            call h5tset_cset_f(mem_type, cset, ierr)
            call check_h5(ierr, where // ': h5tset_cset_f')
            call h5tset_strpad_f(mem_type, pad, ierr)
            call check_h5(ierr, where // ': h5tset_strpad_f')
            allocate(chars(max(int(length), 1)))
            chars = c_null_char
            buffer = c_loc(chars)
            call h5aread_f(attr, mem_type, buffer, status)
            n = size(chars)
            do k = 1, size(chars)
                if (chars(k) == c_null_char) then
                    n = k - 1
                    exit
                end if
            end do
            value = repeat(' ', n)
            do k = 1, n
                value(k:k) = chars(k)
            end do
            if (pad == H5T_STR_SPACEPAD_F) value = trim(value)
        end if
        call h5tclose_f(mem_type, ierr)
        call check_h5(ierr, where // ': h5tclose_f (memory)')
        call h5tclose_f(file_type, ierr)
        call check_h5(ierr, where // ': h5tclose_f (file)')
        call h5aclose_f(attr, ierr)
        call check_h5(ierr, where // ': h5aclose_f')
        status = merge(1, 0, status < 0)
        if (status /= 0) message = "cannot read the string attribute '" // name // "' of '" // &
            file%path // "'"
        call hand_over(status, 'h5_read_attribute', message, stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_attr_text

end module sph_hdf5
