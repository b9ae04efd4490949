!> Snapshot files (schema in doc/output.md): one HDF5 file per output time, written
!> collectively through sph_hdf5, one row per real particle (owned fluid, wall and virtual
!> particles; never ghosts or mirrors), rows grouped by rank.
!>
!> Safe writing: rank 0 makes the folder (mkdir -p), the file is written as `path`.tmp, the
!> root attribute `write_complete` is written last before closing, and rank 0 renames the
!> closed file to `path`; nobody returns before the rename. A file with the final name is
!> therefore whole, and the readers refuse a file without the marker, naming it.
!>
!> Every routine is collective on env%comm and returns the same stat on every rank (agreed
!> with an MPI reduction), so a caller may stop collectively on it. Library convention:
!> optional stat/errmsg; without stat a failure stops through sph_errors.
module sph_snapshot
    use sph_kinds, only: wp, i4, i8
    use sph_mpi_env, only: mpi_env_t, global_max, global_sum, broadcast_text, agreed_status
    use sph_logger, only: int_text, mb_text
    use sph_errors, only: fatal_collective, fatal_abort
    use sph_particles, only: particles_t, particles_reserve, particles_clear, particles_visit, &
        field_list, &
        field_info_t, field_op_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL, FIELD_SNAPSHOT, &
        FIELD_OPTIONAL, FIELD_REAL, FIELD_CHECKPOINT, FIELD_INT
    use sph_hdf5, only: h5_file_t, h5_create, h5_open_read, h5_close, h5_group_create, &
        h5_row_layout, h5_write_rows, h5_read_rows, h5_dataset_rows, h5_write_attribute, &
        h5_read_attribute
    use sph_filesystem, only: make_directories, rename_file, free_bytes, disk_hint, unlink_if_link
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    implicit none
    private
    public :: write_snapshot, snapshot_filename, read_snapshot_header, read_particles_rows
    public :: read_snapshot_rows
    public :: snapshot_begin, snapshot_end, SNAPSHOT_NOT_CLOSED

    !> snapshot_end's status when the file's closing failed (a full disk at HDF5's last
    !> flush): the caller stops through MPI_Abort (sph_errors fatal_collective's abort)
    integer, parameter :: SNAPSHOT_NOT_CLOSED = 4
    public :: snapshot_format_name, snapshot_format_version
    public :: write_particle_fields, read_particle_fields, check_datasets

    character(len=*), parameter :: snapshot_format_name = 'sphremesh-snapshot'
    integer(i4), parameter :: snapshot_format_version = 1

    !> (env, path, time, step, dimension, n_rows [, input_text] [, stat, errmsg])
    interface read_snapshot_header
        module procedure read_header, read_header_with_input
    end interface
    !> The name sph_checkpoint uses for read_particles_rows (one procedure, two names).
    interface read_snapshot_rows
        module procedure read_particles_rows
    end interface

    !> Writes (or reads) the fields of the table selected by `mask` as datasets
    !> particles/<name>: rows(1:n) of the particles at `offset` of `total` (reading: n rows
    !> from `offset` into slots 1..n). Integers of FIELD_INT are int32 in the file.
    type, extends(field_op_t) :: field_io_t
        type(mpi_env_t), pointer :: env => null()
        type(h5_file_t), pointer :: file => null()
        integer :: mask = FIELD_SNAPSHOT
        logical :: reading = .false.
        integer :: n = 0
        integer(i8) :: offset = 0, total = 0
        integer, allocatable :: rows(:)
    contains
        procedure :: real1 => io_real1, real2 => io_real2, int8 => io_int8, int4 => io_int4
    end type field_io_t

contains

    !> `<output_dir>/<case_name>_<step>.h5`, the step with at least 6 digits (more when
    !> step >= 10**6).
    function snapshot_filename(output_dir, case_name, step) result(path)
        character(len=*), intent(in) :: output_dir, case_name
        integer(i8), intent(in) :: step
        character(len=:), allocatable :: path
        character(len=32) :: digits
        write(digits, '(i0.6)') step
        path = trim(output_dir) // '/' // trim(case_name) // '_' // trim(digits) // '.h5'
    end function snapshot_filename

    !> Write one snapshot collectively (every rank, also one without particles). The text
    !> arguments must be the same on every rank (they become attributes).
    subroutine write_snapshot(env, p, path, time, step, dimension, code_version, input_text, &
                              stat, errmsg, with_virtual, dx)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        character(len=*), intent(in) :: path, code_version, input_text
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        integer, intent(in) :: dimension
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        logical, intent(in), optional :: with_virtual   !< rows for virtual particles (default)
        !> the particle spacing of the state (level 0's), stored as the root attribute 'dx' as
        !> a checkpoint stores it: after an in-run refine or coarsen it differs from the
        !> stored input's &domain dx, and the post-processing read the old one (fz43)
        real(wp), intent(in), optional :: dx
        type(h5_file_t) :: file
        integer :: my_stat
        character(len=:), allocatable :: message
        call snapshot_begin(env, p, path, time, step, dimension, code_version, input_text, &
            file, my_stat, message, with_virtual)
        if (my_stat == 0 .and. present(dx)) call h5_write_attribute(file, 'dx', dx)
        if (my_stat == 0) call snapshot_end(env, path, file, my_stat, message)
        call finish(my_stat, message, 'write_snapshot', stat)
        if (present(errmsg)) errmsg = message
    end subroutine write_snapshot

    !> Make the folder, create `path`.tmp and write the root attributes and the particle
    !> datasets; the caller may add more (checkpoints do) before snapshot_end. On failure
    !> (stat /= 0, the same on every rank) no file is left open.
    subroutine snapshot_begin(env, p, path, time, step, dimension, code_version, input_text, &
                              file, stat, errmsg, with_virtual, checkpoint_fields, extra_bytes)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        character(len=*), intent(in) :: path, code_version, input_text
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        integer, intent(in) :: dimension
        type(h5_file_t), intent(inout), target :: file
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        logical, intent(in), optional :: with_virtual
        !> the caller adds the checkpoint fields (write_checkpoint): room for them too
        logical, intent(in), optional :: checkpoint_fields
        !> bytes of text the caller adds (a checkpoint's snapshot index)
        integer, intent(in), optional :: extra_bytes
        integer :: n, i, dir_end, my_stat
        logical :: virtual_rows
        integer(i8) :: offset, total
        integer, allocatable :: rows(:)
        integer(i4), allocatable :: ints(:)
        character(len=:), allocatable :: date

        errmsg = ''
        ! rank 0 makes the folder (libc mkdir through sph_filesystem: no shell, no quoting,
        ! a real status); everybody learns whether it worked
        stat = 0
        dir_end = index(path, '/', back=.true.)
        if (env%rank == 0 .and. dir_end > 1) call make_directories(path(1:dir_end - 1), stat)
        stat = agreed_status(env, stat)
        if (stat /= 0) then
            errmsg = "cannot create the output directory '" // path(1:max(dir_end - 1, 0)) // &
                "' for '" // path // "'"
            return
        end if

        ! the rows: owned particles in their storage order (virtual ones unless left out)
        virtual_rows = .true.
        if (present(with_virtual)) virtual_rows = with_virtual
        allocate(rows(p%n_owned))
        n = 0
        do i = 1, p%n_owned
            if (p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_WALL .or. &
                (p%kind(i) == KIND_VIRTUAL .and. virtual_rows)) then
                n = n + 1
                rows(n) = i
            end if
        end do
        if (dir_end == 1) then
            call check_room('/', global_sum(env, int(n, i8)), len(input_text), stat, errmsg, &
                checkpoint_fields)
        else
            call check_room(path(1:max(dir_end - 1, 0)), global_sum(env, int(n, i8)), &
                len(input_text), stat, errmsg, checkpoint_fields)
        end if
        if (stat /= 0) return

        ! (a link at the .tmp name would have the file written over its target: sph_filesystem)
        if (env%rank == 0) call unlink_if_link(path // '.tmp')
        call h5_create(env, path // '.tmp', file, my_stat, errmsg)
        stat = agreed_status(env, my_stat)
        if (stat /= 0) then
            if (my_stat == 0) call fatal_abort('snapshot_begin', "'" // path // &
                ".tmp' was created on some ranks only")
            return
        end if
        call h5_row_layout(env, n, offset, total)

        ! attributes are metadata: the same value on every rank, so the date is rank 0's
        date = ''
        if (env%rank == 0) date = iso_date_utc()
        call broadcast_text(env, date)
        call h5_write_attribute(file, 'time', time)
        call h5_write_attribute(file, 'step', step)
        call h5_write_attribute(file, 'dimension', int(dimension, i4))
        call h5_write_attribute(file, 'code_version', code_version)
        call h5_write_attribute(file, 'input', input_text)
        call h5_write_attribute(file, 'nranks', int(env%nranks, i4))
        call h5_write_attribute(file, 'date', date)
        call h5_write_attribute(file, 'format', snapshot_format_name)
        call h5_write_attribute(file, 'format_version', snapshot_format_version)

        call h5_group_create(file, 'particles')
        call write_particle_fields(env, file, p, FIELD_SNAPSHOT, rows, n, offset, total)
        allocate(ints(max(n, 1)))
        ints(1:n) = int(env%rank, i4)
        call h5_write_rows(env, file, 'particles/rank', ints, n, offset, total)

    contains

        !> Whether the file system of `folder` ('' = the working directory) has room for a file
        !> of `rows` particles (with the checkpoint fields when asked) and the input text
        !> (collective: rank 0 asks, all agree). A full disk found by HDF5 instead failed in its
        !> close: the ranks crashed in the finalisation that followed, or hung when one rank's
        !> flush failed alone (Open MPI's I/O and HDF5 1.10). The file's size is the rows'
        !> values, at most 8 bytes each, with a margin for the metadata; where the free space
        !> cannot be asked, the write goes ahead. stat 3 and errmsg when there is no room.
        subroutine check_room(folder, rows, text_bytes, stat, errmsg, checkpoint_fields)
            character(len=*), intent(in) :: folder
            integer(i8), intent(in) :: rows
            integer, intent(in) :: text_bytes
            integer, intent(out) :: stat
            character(len=:), allocatable, intent(out) :: errmsg
            logical, intent(in), optional :: checkpoint_fields
            !> HDF5's own share: 12-19 kB on the 10^3-10^4-row files measured, whose data
            !> the estimate below gives to the byte
            integer, parameter :: ROOM_MARGIN = 32 * 1024
            type(field_info_t), allocatable :: fields(:)
            integer(i8) :: need, free, row_bytes
            integer :: f
            logical :: with_checkpoint
            errmsg = ''
            with_checkpoint = .false.
            if (present(checkpoint_fields)) with_checkpoint = checkpoint_fields
            ! each row's values at their stored sizes, and the writing rank (4 bytes)
            fields = field_list(p)
            row_bytes = 4
            do f = 1, size(fields)
                if (iand(fields(f)%flags, FIELD_SNAPSHOT) == 0 .and. .not. (with_checkpoint &
                    .and. iand(fields(f)%flags, FIELD_CHECKPOINT) /= 0)) cycle
                row_bytes = row_bytes + int(fields(f)%width, i8) * &
                    merge(4_i8, 8_i8, fields(f)%storage == FIELD_INT)
            end do
            need = rows * row_bytes
            need = need + need / 100 + int(text_bytes, i8) + ROOM_MARGIN
            if (present(extra_bytes)) need = need + int(extra_bytes, i8)
            free = -1
            if (env%rank == 0) then
                if (len(folder) > 0) then
                    free = free_bytes(folder)
                else
                    free = free_bytes('.')
                end if
            end if
            free = global_max(env, free)
            stat = 0
            if (free < 0 .or. free >= need) return
            stat = 3
            errmsg = "no room for '" // path // "' on its file system (" // &
                mb_text(real(free, wp)) // ' free, the file needs about ' // &
                mb_text(real(need, wp)) // '): nothing of it was written'
        end subroutine check_room
    end subroutine snapshot_begin

    !> The write_complete marker last, close, and rename `path`.tmp to `path` (rank 0). The
    !> closing reduction waits for rank 0's rename, so it is also the barrier after it.
    subroutine snapshot_end(env, path, file, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(inout) :: file
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer :: my_stat
        errmsg = ''
        call h5_write_attribute(file, 'write_complete', 1_i4)
        call h5_close(file, my_stat)
        stat = agreed_status(env, my_stat)
        if (stat /= 0) then
            ! (SNAPSHOT_NOT_CLOSED: the library may hold the file still; its caller stops
            ! through MPI_Abort, since HDF5's clean-up at MPI_Finalize crashed then)
            stat = SNAPSHOT_NOT_CLOSED
            errmsg = "closing '" // path // ".tmp' failed: the snapshot is not complete" // &
                disk_hint(path)
            return
        end if
        if (env%rank == 0) call rename_file(path // '.tmp', path, my_stat)
        stat = agreed_status(env, my_stat)
        if (stat /= 0) errmsg = "cannot rename '" // path // ".tmp' to '" // path // "'"
    end subroutine snapshot_end

    !> The header of a snapshot (or checkpoint). Refuses a file that cannot be opened, lacks
    !> the write_complete marker or is not a sphremesh snapshot of format version 1.
    subroutine read_header(env, path, time, step, dimension, n_rows, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        real(wp), intent(out) :: time
        integer(i8), intent(out) :: step, n_rows   !< n_rows: rows in the file, all ranks
        integer, intent(out) :: dimension
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        character(len=:), allocatable :: input_text, message
        integer :: status
        call header(env, path, time, step, dimension, n_rows, input_text, status, message)
        call finish(status, message, 'read_snapshot_header', stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_header

    !> As read_header, also returning the input text the run was made with.
    subroutine read_header_with_input(env, path, time, step, dimension, n_rows, input_text, &
                                      stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        real(wp), intent(out) :: time
        integer(i8), intent(out) :: step, n_rows
        integer, intent(out) :: dimension
        character(len=:), allocatable, intent(out) :: input_text
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        character(len=:), allocatable :: message
        integer :: status
        call header(env, path, time, step, dimension, n_rows, input_text, status, message)
        call finish(status, message, 'read_snapshot_header', stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_header_with_input

    !> The header, with a status agreed by all ranks and a message naming the file.
    subroutine header(env, path, time, step, dimension, n_rows, input_text, stat, message)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        real(wp), intent(out) :: time
        integer(i8), intent(out) :: step, n_rows
        integer, intent(out) :: dimension
        character(len=:), allocatable, intent(out) :: input_text
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: message
        type(h5_file_t) :: file
        integer :: my_stat
        integer(i4) :: dim4
        time = 0; step = 0; n_rows = 0; dimension = 0; dim4 = 0
        input_text = ''
        call open_checked(env, path, file, my_stat, message)
        if (my_stat == 0) then
            call h5_read_attribute(file, 'time', time, my_stat)
            if (my_stat == 0) call h5_read_attribute(file, 'step', step, my_stat)
            if (my_stat == 0) call h5_read_attribute(file, 'dimension', dim4, my_stat)
            if (my_stat == 0) call h5_read_attribute(file, 'input', input_text, my_stat)
            if (my_stat == 0) call check_datasets(file, n_rows, my_stat, message)
            if (my_stat /= 0 .and. len(message) == 0) message = "'" // path // &
                "' lacks the snapshot attributes (time, step, dimension, input): refused"
            ! values no run writes (a file edited outside sphremesh): a negative step or
            ! time ran on with file names and max_steps off, a NaN time trapped later
            if (my_stat == 0) then
                ! (no comparison with a NaN: it traps where floating-point exceptions do)
                if (.not. ieee_is_finite(time)) time = -1.0_wp
                if (time < 0.0_wp) then
                    my_stat = 1
                    message = "'" // path // "': its time is not finite or is negative: refused"
                else if (step < 0_i8) then
                    my_stat = 1
                    message = "'" // path // "': its step is negative: refused"
                end if
            end if
            dimension = dim4
            call h5_close(file)
        end if
        stat = agreed_status(env, my_stat)
        if (stat /= 0 .and. my_stat == 0) message = "'" // path // "' is refused on another rank"
    end subroutine header

    !> Rows first_row .. first_row + n_rows - 1 (0-based; each rank its own range, possibly
    !> empty) become this rank's owned particles; ghosts are dropped, p%dim is set from the
    !> file, and the fields a snapshot does not hold (start-of-step copies, rates, strain,
    !> wall geometry) are zero. Refuses a file as read_snapshot_header does,
    !> and a range outside the file.
    subroutine read_particles_rows(env, path, p, first_row, n_rows, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(particles_t), intent(inout) :: p
        integer(i8), intent(in) :: first_row
        integer, intent(in) :: n_rows
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        type(h5_file_t), target :: file
        integer(i8) :: total
        integer(i4) :: dim4
        integer :: my_stat, n
        character(len=:), allocatable :: message
        character(len=64) :: numbers

        call open_checked(env, path, file, my_stat, message)
        if (agreed_status(env, my_stat) /= 0) then
            if (my_stat == 0) call fatal_abort('read_particles_rows', "'" // path // &
                "' was opened on some ranks only")
            call finish(1, message, 'read_particles_rows', stat)
            if (present(errmsg)) errmsg = message
            return
        end if
        call check_datasets(file, total, my_stat, message)
        if (my_stat == 0) call h5_read_attribute(file, 'dimension', dim4, my_stat, message)
        if (my_stat == 0 .and. (first_row < 0 .or. n_rows < 0 .or. &
                                first_row + n_rows > total)) then
            my_stat = 1
            write(numbers, '(i0,a,i0,a,i0)') first_row, ' + ', n_rows, ' > ', total
            message = "rows outside '" // path // "' (" // trim(numbers) // ")"
        end if
        if (agreed_status(env, my_stat) /= 0) then
            call h5_close(file)
            if (my_stat == 0) message = "reading '" // path // "' failed on another rank"
            call finish(1, message, 'read_particles_rows', stat)
            if (present(errmsg)) errmsg = message
            return
        end if

        n = n_rows
        p%dim = dim4
        call particles_reserve(p, n)
        ! what a snapshot does not hold (start-of-step copies, rates, strain, wall geometry)
        ! is zero: the next step rebuilds it
        call particles_clear(p, 1, n)
        call read_particle_fields(env, file, p, FIELD_SNAPSHOT, n, first_row)
        call h5_close(file, my_stat)
        p%n_owned = n
        p%n_ghost = 0
        p%n_total = n
        my_stat = agreed_status(env, my_stat)
        message = ''
        if (my_stat /= 0) message = "closing '" // path // "' after reading failed"
        call finish(my_stat, message, 'read_particles_rows', stat)
        if (present(errmsg)) errmsg = message
    end subroutine read_particles_rows

    ! ---- helpers --------------------------------------------------------------------------

    !> Open `path` for reading and check that it is a complete snapshot: the write_complete
    !> marker is 1, format and format_version match. On failure the file is closed again and
    !> the message names it.
    subroutine open_checked(env, path, file, stat, message)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(out) :: file
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: message
        integer(i4) :: complete, version
        character(len=:), allocatable :: format
        message = ''
        call h5_open_read(env, path, file, stat, message)
        if (stat /= 0) return
        call h5_read_attribute(file, 'write_complete', complete, stat)
        if (stat /= 0 .or. complete /= 1) then
            stat = 1
            message = "'" // path // "' is incomplete (no write_complete marker): refused"
        else
            call h5_read_attribute(file, 'format', format, stat)
            if (stat == 0) call h5_read_attribute(file, 'format_version', version, stat)
            if (stat /= 0) then
                message = "'" // path // "' is not a sphremesh snapshot (no format " // &
                    "attributes): refused"
            else if (format /= snapshot_format_name .or. &
                     version /= snapshot_format_version) then
                stat = 1
                message = "'" // path // "' has format '" // format // &
                    "' version " // int_text(int(version, i8)) // ", not '" // &
                    snapshot_format_name // "' version " // &
                    int_text(int(snapshot_format_version, i8)) // ": refused"
            end if
        end if
        if (stat /= 0) call h5_close(file)
    end subroutine open_checked

    !> Every dataset of the fields selected by mask (default FIELD_SNAPSHOT; with p, its
    !> run-time fields too) present (and the rank dataset, for snapshot fields), of the right
    !> width, all with the same rows.
    subroutine check_datasets(file, rows, stat, message, mask, p)
        type(h5_file_t), intent(in) :: file
        integer(i8), intent(out) :: rows
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: message
        integer, intent(in), optional :: mask
        type(particles_t), intent(in), optional :: p
        type(field_info_t), allocatable :: fields(:)
        integer :: k, selection
        selection = FIELD_SNAPSHOT
        if (present(mask)) selection = mask
        stat = 0
        message = ''
        ! (counted by the positions, which every file has: counted by the ids, a missing or
        ! short id dataset was reported as the positions')
        rows = h5_dataset_rows(file, 'particles/position')
        fields = field_list(p)
        do k = 1, size(fields)
            if (iand(fields(k)%flags, selection) == 0) cycle
            ! an optional field may be absent (older files, files made by users)
            if (iand(fields(k)%flags, FIELD_OPTIONAL) /= 0 .and. &
                h5_dataset_rows(file, 'particles/' // trim(fields(k)%name)) < 0) cycle
            call check_one(trim(fields(k)%name), merge(0, fields(k)%width, &
                fields(k)%width == 1), fields(k)%storage /= FIELD_REAL)
            if (stat /= 0) return
        end do
        if (iand(selection, FIELD_SNAPSHOT) /= 0) call check_one('rank', 0, .true.)
    contains
        subroutine check_one(name, expected_width, integral)
            character(len=*), intent(in) :: name
            integer, intent(in) :: expected_width
            logical, intent(in) :: integral   !< an integer field
            integer :: width
            integer(i8) :: these
            logical :: floats
            these = h5_dataset_rows(file, 'particles/' // name, width, floats)
            if (these < 0 .or. these /= rows .or. width /= expected_width) then
                stat = 1
                message = "'" // file%path // "': the dataset /particles/" // name // &
                    " is missing or has the wrong shape: refused"
            else if (integral .eqv. floats) then
                ! HDF5 would convert them: floats rounded to integers (a NaN traps where
                ! floating-point exceptions do), positions written as integers read as such
                stat = 1
                if (integral) then
                    message = "'" // file%path // "': the dataset /particles/" // name // &
                        ' holds floating-point values where integers belong: refused'
                else
                    message = "'" // file%path // "': the dataset /particles/" // name // &
                        ' holds integers where floating-point values belong: refused'
                end if
            end if
        end subroutine check_one
    end subroutine check_datasets

    !> Write the fields selected by mask (FIELD_SNAPSHOT, FIELD_CHECKPOINT) of particles
    !> rows(1:n) as rows offset+1.. of particles/<name> (collective).
    subroutine write_particle_fields(env, file, p, mask, rows, n, offset, total)
        type(mpi_env_t), intent(in), target :: env
        type(h5_file_t), intent(in), target :: file
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask, n
        integer, intent(in) :: rows(:)
        integer(i8), intent(in) :: offset, total
        type(field_io_t) :: op
        op%env => env
        op%file => file
        op%mask = mask
        op%n = n
        op%rows = rows(1:n)
        op%offset = offset
        op%total = total
        call particles_visit(p, op)
    end subroutine write_particle_fields

    !> Read rows offset+1..offset+n of the fields selected by mask into slots 1..n (the
    !> datasets must exist: check_datasets first).
    subroutine read_particle_fields(env, file, p, mask, n, offset)
        type(mpi_env_t), intent(in), target :: env
        type(h5_file_t), intent(in), target :: file
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask, n
        integer(i8), intent(in) :: offset
        type(field_io_t) :: op
        op%env => env
        op%file => file
        op%mask = mask
        op%reading = .true.
        op%n = n
        op%offset = offset
        call particles_visit(p, op)
    end subroutine read_particle_fields

    !> Reading an optional field the file lacks: the particles read get its default, zero.
    logical function missing_optional(op, info)
        type(field_io_t), intent(in) :: op
        type(field_info_t), intent(in) :: info
        missing_optional = .false.
        if (.not. op%reading .or. iand(info%flags, FIELD_OPTIONAL) == 0) return
        missing_optional = h5_dataset_rows(op%file, 'particles/' // trim(info%name)) < 0
    end function missing_optional

    subroutine io_real1(op, a, info)
        class(field_io_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        real(wp), allocatable :: buffer(:)
        if (iand(info%flags, op%mask) == 0) return
        if (missing_optional(op, info)) then
            a(1:op%n) = 0.0_wp
            return
        end if
        allocate(buffer(max(op%n, 1)))
        if (op%reading) then
            call h5_read_rows(op%file, 'particles/' // trim(info%name), buffer, op%n, op%offset)
            a(1:op%n) = buffer(1:op%n)
        else
            buffer(1:op%n) = a(op%rows)
            call h5_write_rows(op%env, op%file, 'particles/' // trim(info%name), buffer, op%n, &
                op%offset, op%total)
        end if
    end subroutine io_real1

    subroutine io_real2(op, a, info)
        class(field_io_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        real(wp), allocatable :: buffer(:, :), column(:)
        if (iand(info%flags, op%mask) == 0) return
        if (missing_optional(op, info)) then
            a(:, 1:op%n) = 0.0_wp
            return
        end if
        if (info%width == 1) then
            ! one value per particle: a one-dimensional dataset, like the rank-1 fields
            allocate(column(max(op%n, 1)))
            if (op%reading) then
                call h5_read_rows(op%file, 'particles/' // trim(info%name), column, op%n, &
                    op%offset)
                a(1, 1:op%n) = column(1:op%n)
            else
                column(1:op%n) = a(1, op%rows)
                call h5_write_rows(op%env, op%file, 'particles/' // trim(info%name), column, &
                    op%n, op%offset, op%total)
            end if
            return
        end if
        allocate(buffer(info%width, max(op%n, 1)))
        if (op%reading) then
            call h5_read_rows(op%file, 'particles/' // trim(info%name), buffer, op%n, op%offset)
            a(:, 1:op%n) = buffer(:, 1:op%n)
        else
            buffer(:, 1:op%n) = a(:, op%rows)
            call h5_write_rows(op%env, op%file, 'particles/' // trim(info%name), buffer, op%n, &
                op%offset, op%total)
        end if
    end subroutine io_real2

    subroutine io_int8(op, a, info)
        class(field_io_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer(i8), allocatable :: buffer(:)
        if (iand(info%flags, op%mask) == 0) return
        if (missing_optional(op, info)) then
            a(1:op%n) = 0
            return
        end if
        allocate(buffer(max(op%n, 1)))
        if (op%reading) then
            call h5_read_rows(op%file, 'particles/' // trim(info%name), buffer, op%n, op%offset)
            a(1:op%n) = buffer(1:op%n)
        else
            buffer(1:op%n) = a(op%rows)
            call h5_write_rows(op%env, op%file, 'particles/' // trim(info%name), buffer, op%n, &
                op%offset, op%total)
        end if
    end subroutine io_int8

    subroutine io_int4(op, a, info)
        class(field_io_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer(i4), allocatable :: buffer(:)
        if (iand(info%flags, op%mask) == 0) return
        if (missing_optional(op, info)) then
            a(1:op%n) = 0
            return
        end if
        allocate(buffer(max(op%n, 1)))
        if (op%reading) then
            call h5_read_rows(op%file, 'particles/' // trim(info%name), buffer, op%n, op%offset)
            a(1:op%n) = buffer(1:op%n)
        else
            buffer(1:op%n) = int(a(op%rows), i4)
            call h5_write_rows(op%env, op%file, 'particles/' // trim(info%name), buffer, op%n, &
                op%offset, op%total)
        end if
    end subroutine io_int4


    !> Hand the (agreed) status to the caller, or stop collectively when it did not ask. The
    !> public routine sets errmsg itself: gfortran 12 loses the length of an optional
    !> deferred-length character dummy passed on to another optional dummy.
    subroutine finish(my_stat, message, where, stat)
        integer, intent(in) :: my_stat
        character(len=*), intent(in) :: message, where
        integer, intent(out), optional :: stat
        if (present(stat)) then
            stat = my_stat
        else if (my_stat /= 0) then
            call fatal_collective(where, message)
        end if
    end subroutine finish


    !> Now in UTC, ISO 8601 (2026-05-09T07:29:33Z): the local time of date_and_time less
    !> its UTC offset, through days since 1970-01-01 (H. Hinnant's civil-date algorithms).
    function iso_date_utc() result(text)
        character(len=:), allocatable :: text
        integer :: values(8), offset_minutes, y, m, d
        integer(i8) :: seconds, days, second_of_day
        character(len=32) :: buffer
        call date_and_time(values=values)
        offset_minutes = values(4)
        if (offset_minutes == -huge(0)) offset_minutes = 0   ! unknown: take local as UTC
        seconds = days_from_civil(values(1), values(2), values(3)) * 86400_i8 + &
            values(5) * 3600_i8 + values(6) * 60_i8 + values(7) - offset_minutes * 60_i8
        second_of_day = modulo(seconds, 86400_i8)
        days = (seconds - second_of_day) / 86400_i8
        call civil_from_days(days, y, m, d)
        write(buffer, '(i4.4,"-",i2.2,"-",i2.2,"T",i2.2,":",i2.2,":",i2.2,"Z")') y, m, d, &
            int(second_of_day / 3600), int(mod(second_of_day, 3600_i8) / 60), &
            int(mod(second_of_day, 60_i8))
        text = trim(buffer)
    end function iso_date_utc

    pure integer(i8) function days_from_civil(year, month, day) result(days)
        integer, intent(in) :: year, month, day
        integer(i8) :: y, era, yoe, doy, doe
        y = year - merge(1, 0, month <= 2)
        era = merge(y, y - 399, y >= 0) / 400
        yoe = y - era * 400
        doy = (153 * (month + merge(-3, 9, month > 2)) + 2) / 5 + day - 1
        doe = yoe * 365 + yoe / 4 - yoe / 100 + doy
        days = era * 146097 + doe - 719468
    end function days_from_civil

    pure subroutine civil_from_days(days, year, month, day)
        integer(i8), intent(in) :: days
        integer, intent(out) :: year, month, day
        integer(i8) :: z, era, doe, yoe, doy, mp
        z = days + 719468
        era = merge(z, z - 146096, z >= 0) / 146097
        doe = z - era * 146097
        yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365
        doy = doe - (365 * yoe + yoe / 4 - yoe / 100)
        mp = (5 * doy + 2) / 153
        day = int(doy - (153 * mp + 2) / 5 + 1)
        month = int(merge(mp + 3, mp - 9, mp < 10))
        year = int(yoe + era * 400) + merge(1, 0, month <= 2)
    end subroutine civil_from_days
end module sph_snapshot
