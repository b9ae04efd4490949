!> Snapshot files (schema in doc/output.md): one HDF5 file per output time, written
!> collectively, one row per real particle (owned fluid, wall and virtual particles; never
!> ghosts or mirrors). Written under a temporary name, completed by a `write_complete`
!> attribute written last, then renamed, so a file with the final name is always whole.
module sph_snapshot
    use sph_kinds, only: wp, i4, i8
    use sph_mpi_env, only: mpi_env_t, global_sum, global_max
    use sph_errors, only: fatal_collective
    use sph_particles, only: particles_t, particles_reserve, KIND_FLUID, KIND_WALL, KIND_VIRTUAL
    use sph_hdf5, only: h5_file_t, h5_create, h5_open_read, h5_close, h5_group_create, &
        h5_write_rows, h5_read_rows, h5_dataset_rows, h5_write_attribute, h5_read_attribute, &
        h5_attribute_exists
    use sph_filesystem, only: make_directories, rename_file
    implicit none
    private
    public :: write_snapshot, snapshot_filename, read_snapshot_header, read_snapshot_rows
    public :: snapshot_format_version, snapshot_begin, snapshot_end

    integer(i4), parameter :: snapshot_format_version = 1


contains

    !> <dir>/<case>_<step, at least 6 digits>.h5
    function snapshot_filename(output_dir, case_name, step) result(path)
        character(len=*), intent(in) :: output_dir, case_name
        integer(i8), intent(in) :: step
        character(len=:), allocatable :: path
        character(len=32) :: digits
        write(digits, '(i6.6)') step
        path = trim(output_dir) // '/' // trim(case_name) // '_' // trim(adjustl(digits)) // '.h5'
    end function snapshot_filename

    subroutine write_snapshot(env, p, path, time, step, dimension, code_version, input_text, &
                              stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(in) :: p
        character(len=*), intent(in) :: path, code_version, input_text
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        integer, intent(in) :: dimension
        integer, intent(out), optional :: stat
        character(len=:), allocatable, intent(out), optional :: errmsg
        type(h5_file_t) :: file
        integer :: my_stat
        character(len=:), allocatable :: message
        call snapshot_begin(env, p, path, time, step, dimension, code_version, input_text, &
            file, my_stat, message)
        if (my_stat == 0) call snapshot_end(env, path, file, my_stat, message)
        if (present(stat)) then
            stat = my_stat
            if (present(errmsg)) errmsg = message
        else if (my_stat /= 0) then
            call fatal_collective('write_snapshot', message)
        end if
    end subroutine write_snapshot

    !> Create `path`.tmp and write the attributes and particle datasets; the caller may add
    !> more (checkpoints do) before snapshot_end.
    subroutine snapshot_begin(env, p, path, time, step, dimension, code_version, input_text, &
                              file, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(in) :: p
        character(len=*), intent(in) :: path, code_version, input_text
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        integer, intent(in) :: dimension
        type(h5_file_t), intent(out) :: file
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer :: n, i, k, dir_end
        integer, allocatable :: rows(:)
        real(wp), allocatable :: v3(:, :), v1(:)
        integer(i8), allocatable :: ids(:)
        integer(i4), allocatable :: ints(:)

        errmsg = ''
        ! rank 0 makes the directory; everybody learns whether it worked
        stat = 0
        dir_end = index(path, '/', back=.true.)
        if (env%rank == 0 .and. dir_end > 1) call make_directories(path(1:dir_end - 1), stat)
        if (global_max(env, int(stat, i8)) /= 0) then
            stat = 1
            errmsg = "cannot create the output directory '" // path(1:max(dir_end - 1, 0)) // "'"
            return
        end if
        call h5_create(env, path // '.tmp', file, stat)
        if (stat /= 0) then
            errmsg = "cannot create the file '" // path // ".tmp'"
            return
        end if
        ! rows: owned real particles
        allocate(rows(p%n_owned))
        n = 0
        do i = 1, p%n_owned
            if (p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_WALL .or. &
                p%kind(i) == KIND_VIRTUAL) then
                n = n + 1
                rows(n) = i
            end if
        end do
        call h5_write_attribute(file, 'time', time)
        call h5_write_attribute(file, 'step', step)
        call h5_write_attribute(file, 'dimension', int(dimension, i4))
        call h5_write_attribute(file, 'code_version', code_version)
        call h5_write_attribute(file, 'input', input_text)
        call h5_write_attribute(file, 'nranks', int(env%nranks, i4))
        call h5_write_attribute(file, 'date', iso_date())
        call h5_write_attribute(file, 'format', 'sphremesh-snapshot')
        call h5_write_attribute(file, 'format_version', snapshot_format_version)
        call h5_group_create(file, 'particles')
        allocate(v3(3, max(n, 1)), v1(max(n, 1)), ids(max(n, 1)), ints(max(n, 1)))
        do k = 1, n
            v3(:, k) = p%x(:, rows(k))
        end do
        call h5_write_rows(env, file, 'particles/position', v3, n)
        do k = 1, n
            v3(:, k) = p%v(:, rows(k))
        end do
        call h5_write_rows(env, file, 'particles/velocity', v3, n)
        v1(1:n) = p%rho(rows(1:n))
        call h5_write_rows(env, file, 'particles/density', v1, n)
        v1(1:n) = p%p(rows(1:n))
        call h5_write_rows(env, file, 'particles/pressure', v1, n)
        v1(1:n) = p%m(rows(1:n))
        call h5_write_rows(env, file, 'particles/mass', v1, n)
        v1(1:n) = p%h(rows(1:n))
        call h5_write_rows(env, file, 'particles/smoothing_length', v1, n)
        v1(1:n) = p%e(rows(1:n))
        call h5_write_rows(env, file, 'particles/energy', v1, n)
        ids(1:n) = p%id(rows(1:n))
        call h5_write_rows(env, file, 'particles/id', ids, n)
        ints(1:n) = int(p%kind(rows(1:n)), i4)
        call h5_write_rows(env, file, 'particles/kind', ints, n)
        ints(1:n) = int(p%level(rows(1:n)), i4)
        call h5_write_rows(env, file, 'particles/level', ints, n)
        ints(1:n) = int(env%rank, i4)
        call h5_write_rows(env, file, 'particles/rank', ints, n)
    end subroutine snapshot_begin

    !> The write_complete marker last, close, and rename `path`.tmp to `path` (rank 0).
    subroutine snapshot_end(env, path, file, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t), intent(inout) :: file
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        errmsg = ''
        call h5_write_attribute(file, 'write_complete', 1_i4)
        call h5_close(file)
        stat = 0
        if (env%rank == 0) call rename_file(path // '.tmp', path, stat)
        if (global_max(env, int(stat, i8)) /= 0) then
            stat = 1
            errmsg = "cannot rename '" // path // ".tmp' to '" // path // "'"
        end if
    end subroutine snapshot_end

    !> Header of a snapshot; refuses (stat /= 0, message naming the file) a file that cannot
    !> be opened or lacks the write_complete marker.
    subroutine read_snapshot_header(env, path, time, step, dimension, n_rows, input_text, &
                                    stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        real(wp), intent(out) :: time
        integer(i8), intent(out) :: step, n_rows
        integer, intent(out) :: dimension
        character(len=:), allocatable, intent(out) :: input_text
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        type(h5_file_t) :: file
        integer(i4) :: dim4, complete
        errmsg = ''
        time = 0; step = 0; n_rows = 0; dimension = 0
        input_text = ''
        call h5_open_read(env, path, file, stat)
        if (stat /= 0) then
            errmsg = "cannot open '" // path // "' as an HDF5 file (missing or truncated)"
            return
        end if
        call h5_read_attribute(file, 'write_complete', complete, stat)
        if (stat /= 0 .or. complete /= 1) then
            stat = 1
            errmsg = "'" // path // "' is incomplete (no write_complete marker): refused"
            call h5_close(file)
            return
        end if
        call h5_read_attribute(file, 'time', time, stat)
        if (stat == 0) call h5_read_attribute(file, 'step', step, stat)
        if (stat == 0) call h5_read_attribute(file, 'dimension', dim4, stat)
        if (stat == 0) call h5_read_attribute(file, 'input', input_text, stat)
        dimension = dim4
        n_rows = h5_dataset_rows(file, 'particles/id')
        if (stat /= 0 .or. n_rows < 0) then
            stat = 1
            errmsg = "'" // path // "' lacks the snapshot attributes or datasets"
        end if
        call h5_close(file)
    end subroutine read_snapshot_header

    !> Rows first_row .. first_row + n - 1 (0-based) become this rank's owned particles.
    subroutine read_snapshot_rows(env, path, p, first_row, n, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(particles_t), intent(inout) :: p
        integer(i8), intent(in) :: first_row
        integer, intent(in) :: n
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        type(h5_file_t) :: file
        real(wp), allocatable :: v3(:, :), v1(:)
        integer(i8), allocatable :: ids(:)
        integer(i4), allocatable :: ints(:)
        errmsg = ''
        call h5_open_read(env, path, file, stat)
        if (stat /= 0) then
            errmsg = "cannot open '" // path // "'"
            return
        end if
        if (.not. h5_attribute_exists(file, 'write_complete')) then
            stat = 1
            errmsg = "'" // path // "' is incomplete (no write_complete marker): refused"
            call h5_close(file)
            return
        end if
        call particles_reserve(p, n)
        allocate(v3(3, max(n, 1)), v1(max(n, 1)), ids(max(n, 1)), ints(max(n, 1)))
        call h5_read_rows(file, 'particles/position', v3, n, first_row)
        p%x(:, 1:n) = v3(:, 1:n)
        call h5_read_rows(file, 'particles/velocity', v3, n, first_row)
        p%v(:, 1:n) = v3(:, 1:n)
        call h5_read_rows(file, 'particles/density', v1, n, first_row)
        p%rho(1:n) = v1(1:n)
        call h5_read_rows(file, 'particles/pressure', v1, n, first_row)
        p%p(1:n) = v1(1:n)
        call h5_read_rows(file, 'particles/mass', v1, n, first_row)
        p%m(1:n) = v1(1:n)
        call h5_read_rows(file, 'particles/smoothing_length', v1, n, first_row)
        p%h(1:n) = v1(1:n)
        call h5_read_rows(file, 'particles/energy', v1, n, first_row)
        p%e(1:n) = v1(1:n)
        call h5_read_rows(file, 'particles/id', ids, n, first_row)
        p%id(1:n) = ids(1:n)
        call h5_read_rows(file, 'particles/kind', ints, n, first_row)
        p%kind(1:n) = ints(1:n)
        call h5_read_rows(file, 'particles/level', ints, n, first_row)
        p%level(1:n) = ints(1:n)
        p%n_owned = n
        p%n_ghost = 0
        p%n_total = n
        call h5_close(file)
        stat = 0
    end subroutine read_snapshot_rows

    !> Current UTC date and time, ISO 8601.
    function iso_date() result(text)
        character(len=:), allocatable :: text
        integer :: values(8)
        character(len=32) :: buffer
        integer :: minutes
        call date_and_time(values=values)
        ! values(4) is the local offset from UTC in minutes; write local time with its offset
        minutes = values(4)
        write(buffer, '(i4.4,a,i2.2,a,i2.2,a,i2.2,a,i2.2,a,i2.2,a,i2.2,a,i2.2)') values(1), '-', &
            values(2), '-', values(3), 'T', values(5), ':', values(6), ':', values(7), &
            merge('+', '-', minutes >= 0), abs(minutes) / 60, ':', mod(abs(minutes), 60)
        text = trim(buffer)
    end function iso_date
end module sph_snapshot
