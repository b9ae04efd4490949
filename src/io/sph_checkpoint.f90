!> A checkpoint is a snapshot file plus what a bit-for-bit continuation needs (each particle's
!> wall geometry, every rank's row count and the ORB tree, the snapshot index of the run),
!> written as safely as snapshots (temporary name, write_complete last, rename). On the same
!> rank count each rank gets back exactly its particles in their order and the same
!> decomposition, so the continued run repeats the uninterrupted one bit for bit; on another
!> rank count the rows are shared out evenly and the caller rebuilds the decomposition.
module sph_checkpoint
    use sph_kinds, only: wp, i4, i8
    use sph_mpi_env, only: mpi_env_t, broadcast_text, agreed_status, global_max
    use sph_particles, only: particles_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL, FIELD_CHECKPOINT
    use sph_domain, only: domain_t, domain_set_tree, domain_tree_valid
    use sph_logger, only: log_warn
    use sph_hdf5, only: h5_file_t, h5_open_read, h5_close, h5_group_create, h5_write_rows, &
        h5_read_rows, h5_dataset_rows, h5_write_attribute, h5_read_attribute, h5_row_layout, &
        h5_attribute_exists
    use sph_filesystem, only: list_directory
    use sph_snapshot, only: snapshot_begin, snapshot_end, read_snapshot_header, &
        read_snapshot_rows, write_particle_fields, read_particle_fields, check_datasets
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    implicit none
    private
    public :: write_checkpoint, read_checkpoint, checkpoint_filename, find_latest_checkpoint
    public :: has_checkpoint, checkpoint_names
    public :: checkpoint_format_version, stored_spacing

    integer(i4), parameter :: checkpoint_format_version = 1


contains

    !> <output_dir>/<case>_checkpoint_<step, 6 digits or more>.h5
    function checkpoint_filename(output_dir, case_name, step) result(path)
        character(len=*), intent(in) :: output_dir, case_name
        integer(i8), intent(in) :: step
        character(len=:), allocatable :: path
        character(len=32) :: digits
        write(digits, '(i0.6)') step
        path = trim(output_dir) // '/' // trim(case_name) // '_checkpoint_' // &
            trim(adjustl(digits)) // '.h5'
    end function checkpoint_filename

    !> dx, when given, is stored as the root attribute 'dx': the particle spacing of the
    !> state (after a refine or coarsen it differs from the input's &domain dx, which a
    !> restart checks, see read_checkpoint). stat 2: an owned particle of a kind no
    !> checkpoint holds (an internal error); other failures (the file) stat 1.
    subroutine write_checkpoint(env, p, domain, path, time, step, dimension, code_version, &
                                input_text, snapshot_index, stat, errmsg, dx, balance, &
                                force_sums)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        type(domain_t), intent(in) :: domain
        character(len=*), intent(in) :: path, code_version, input_text, snapshot_index
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        integer, intent(in) :: dimension
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        real(wp), intent(in), optional :: dx
        !> a multi-resolution run's balance of its levels (sph_stepper: the reference mass,
        !> each level's last virtual push, the zones' drift), stored as
        !> 'checkpoint/level_balance'
        real(wp), intent(in), optional, contiguous :: balance(:)
        !> the forces file's mean since its last row (sph_stepper: the window, then the force
        !> integrals over it), stored as 'checkpoint/force_sums': a restart's next row then
        !> averages the steps the checkpointed run had taken since that row too
        real(wp), intent(in), optional, contiguous :: force_sums(:)
        type(h5_file_t) :: file
        integer :: n, n_tree, k
        integer(i8) :: my_rows(1), offset, total
        real(wp), allocatable :: cuts(:)
        integer(i4), allocatable :: tree(:)

        ! every owned particle is a real one (ghosts and mirrors live after n_owned), so the
        ! snapshot rows are exactly 1..n_owned in order
        n = p%n_owned
        ! (agreed over the ranks: a rank that returned alone left the others waiting in the
        ! collective write, a hang)
        if (agreed_status(env, merge(1, 0, any(p%kind(1:n) /= KIND_FLUID .and. &
                p%kind(1:n) /= KIND_WALL .and. p%kind(1:n) /= KIND_VIRTUAL))) /= 0) then
            stat = 2
            errmsg = 'write_checkpoint: an owned particle of an unexpected kind (an ' // &
                'internal error)'
            return
        end if
        call snapshot_begin(env, p, path, time, step, dimension, code_version, input_text, &
            file, stat, errmsg, checkpoint_fields=.true., extra_bytes=len(snapshot_index))
        if (stat /= 0) return
        call h5_write_attribute(file, 'checkpoint_format_version', checkpoint_format_version)
        call h5_write_attribute(file, 'snapshot_index', snapshot_index)
        if (present(dx)) call h5_write_attribute(file, 'dx', dx)
        call h5_row_layout(env, n, offset, total)
        call write_particle_fields(env, file, p, FIELD_CHECKPOINT, [(k, k = 1, n)], n, offset, &
            total)
        call h5_group_create(file, 'checkpoint')
        my_rows = int(n, i8)
        call h5_write_rows(env, file, 'checkpoint/rank_rows', my_rows, 1)
        ! the ORB tree, from rank 0 (every rank holds the same tree)
        n_tree = merge(domain%n_nodes, 0, env%rank == 0)
        allocate(tree(max(domain%n_nodes, 1)), cuts(max(domain%n_nodes, 1)))
        cuts(1:domain%n_nodes) = domain%node_cut(1:domain%n_nodes)
        call h5_write_rows(env, file, 'checkpoint/orb_cut', cuts, n_tree)
        tree(1:domain%n_nodes) = int(domain%node_axis(1:domain%n_nodes), i4)
        call h5_write_rows(env, file, 'checkpoint/orb_axis', tree, n_tree)
        tree(1:domain%n_nodes) = int(domain%node_left(1:domain%n_nodes), i4)
        call h5_write_rows(env, file, 'checkpoint/orb_left', tree, n_tree)
        tree(1:domain%n_nodes) = int(domain%node_right(1:domain%n_nodes), i4)
        call h5_write_rows(env, file, 'checkpoint/orb_right', tree, n_tree)
        tree(1:domain%n_nodes) = int(domain%node_rank(1:domain%n_nodes), i4)
        call h5_write_rows(env, file, 'checkpoint/orb_rank', tree, n_tree)
        if (present(balance)) call h5_write_rows(env, file, 'checkpoint/level_balance', &
            balance, merge(size(balance), 0, env%rank == 0))
        if (present(force_sums)) call h5_write_rows(env, file, 'checkpoint/force_sums', &
            force_sums, merge(size(force_sums), 0, env%rank == 0))
        call snapshot_end(env, path, file, stat, errmsg)
    end subroutine write_checkpoint

    !> Read a checkpoint into p (owned particles). same_layout is true when the file was
    !> written on this many ranks: then the decomposition in `domain` is restored too;
    !> otherwise the caller must partition and migrate. Refuses incomplete or foreign files.
    !> dx: the particle spacing stored by write_checkpoint, 0 when the file has none.
    subroutine read_checkpoint(env, path, p, domain, time, step, input_text, snapshot_index, &
                               same_layout, stat, errmsg, dx, balance, force_sums)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(particles_t), intent(inout) :: p
        type(domain_t), intent(inout) :: domain
        real(wp), intent(out) :: time
        integer(i8), intent(out) :: step
        character(len=:), allocatable, intent(out) :: input_text, snapshot_index
        logical, intent(out) :: same_layout
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        real(wp), intent(out), optional :: dx
        !> what write_checkpoint stored as `balance`; empty when the file holds none
        real(wp), allocatable, intent(out), optional :: balance(:)
        !> what write_checkpoint stored as `force_sums`; empty when the file holds none
        real(wp), allocatable, intent(out), optional :: force_sums(:)
        type(h5_file_t) :: file
        integer :: dimension, n, n_tree
        integer(i4) :: version, nranks_file
        integer(i8) :: n_rows, offset, share, extra
        integer(i8), allocatable :: rank_rows(:)
        integer(i4), allocatable :: axis(:), left(:), right(:), ranks(:)
        real(wp), allocatable :: cuts(:)
        character(len=:), allocatable :: message
        logical :: stored_layout   !< a layout for this rank count is stored (whole or not)

        same_layout = .false.
        snapshot_index = ''
        call read_snapshot_header(env, path, time, step, dimension, n_rows, input_text, stat, &
            errmsg)
        if (stat /= 0) return
        call h5_open_read(env, path, file, stat)
        if (stat /= 0) then
            errmsg = "cannot open '" // path // "'"
            return
        end if
        call h5_read_attribute(file, 'checkpoint_format_version', version, stat)
        if (stat /= 0 .or. version /= checkpoint_format_version) then
            stat = 1
            errmsg = "'" // path // "' is not a sphremesh checkpoint of format version 1 " // &
                "(a snapshot, or written by an incompatible version): refused"
            call h5_close(file)
            return
        end if
        call h5_read_attribute(file, 'snapshot_index', snapshot_index, stat)
        if (present(dx)) then
            dx = file_spacing(file)
            ! (a NaN was ignored in Release and trapped in Debug)
            if (dx < 0.0_wp) then
                stat = 1
                errmsg = "'" // path // "': its attribute dx is not a positive spacing: refused"
                call h5_close(file)
                return
            end if
        end if
        if (present(balance)) then
            n = int(max(h5_dataset_rows(file, 'checkpoint/level_balance'), 0_i8))
            allocate(balance(n))
            if (n > 0) call h5_read_rows(file, 'checkpoint/level_balance', balance, n, 0_i8)
        end if
        if (present(force_sums)) then
            n = int(max(h5_dataset_rows(file, 'checkpoint/force_sums'), 0_i8))
            allocate(force_sums(n))
            if (n > 0) call h5_read_rows(file, 'checkpoint/force_sums', force_sums, n, 0_i8)
        end if
        call h5_read_attribute(file, 'nranks', nranks_file, stat)
        same_layout = nranks_file == env%nranks .and. &
            h5_dataset_rows(file, 'checkpoint/rank_rows') == env%nranks
        stored_layout = same_layout
        if (same_layout) then
            allocate(rank_rows(env%nranks))
            call h5_read_rows(file, 'checkpoint/rank_rows', rank_rows, env%nranks, 0_i8)
            offset = sum(rank_rows(1:env%rank))
            n = int(rank_rows(env%rank + 1))
            ! the stored decomposition, when it is whole: a damaged one (edited outside
            ! sphremesh) is rebuilt instead, as for another rank count (it indexed out of
            ! bounds, or a NaN cut trapped)
            n_tree = int(h5_dataset_rows(file, 'checkpoint/orb_axis'))
            same_layout = n_tree >= 1 .and. all(rank_rows >= 0) .and. &
                sum(rank_rows) == n_rows .and. &
                h5_dataset_rows(file, 'checkpoint/orb_left') == n_tree .and. &
                h5_dataset_rows(file, 'checkpoint/orb_right') == n_tree .and. &
                h5_dataset_rows(file, 'checkpoint/orb_rank') == n_tree .and. &
                h5_dataset_rows(file, 'checkpoint/orb_cut') == n_tree
        end if
        if (same_layout) then
            allocate(axis(n_tree), left(n_tree), right(n_tree), ranks(n_tree), cuts(n_tree))
            call h5_read_rows(file, 'checkpoint/orb_axis', axis, n_tree, 0_i8)
            call h5_read_rows(file, 'checkpoint/orb_left', left, n_tree, 0_i8)
            call h5_read_rows(file, 'checkpoint/orb_right', right, n_tree, 0_i8)
            call h5_read_rows(file, 'checkpoint/orb_rank', ranks, n_tree, 0_i8)
            call h5_read_rows(file, 'checkpoint/orb_cut', cuts, n_tree, 0_i8)
            same_layout = domain_tree_valid(int(axis), int(left), int(right), int(ranks), &
                cuts, dimension, env%nranks)
        end if
        if (stored_layout .and. .not. same_layout) call log_warn("restart: the " // &
            "decomposition stored in '" // path // "' is damaged; it is made anew")
        if (same_layout) then
            call domain_set_tree(domain, int(axis), int(left), int(right), int(ranks), cuts)
        else
            share = n_rows / env%nranks
            extra = mod(n_rows, int(env%nranks, i8))
            n = int(share + merge(1_i8, 0_i8, env%rank < extra))
            offset = env%rank * share + min(int(env%rank, i8), extra)
        end if
        call h5_close(file)
        call read_snapshot_rows(env, path, p, offset, n, stat, errmsg)
        if (stat /= 0) return
        ! then what only checkpoints hold, over the defaults the snapshot reader set
        call h5_open_read(env, path, file, stat)
        if (stat /= 0) then
            errmsg = "'" // path // "': cannot be opened again for its checkpoint " // &
                'datasets: refused'
            return
        end if
        call check_datasets(file, n_rows, stat, message, FIELD_CHECKPOINT, p)
        if (stat /= 0) then
            ! (check_datasets names the dataset and what is wrong with it)
            errmsg = message
            call h5_close(file)
            return
        end if
        call read_particle_fields(env, file, p, FIELD_CHECKPOINT, n, offset)
        call h5_close(file)
    end subroutine read_checkpoint

    !> The particle spacing a checkpoint records (attribute 'dx'), 0 when the file has none
    !> or cannot be read (a snapshot; collective); -1 when it has one that is no spacing (not
    !> finite or not positive: a file edited outside sphremesh).
    real(wp) function stored_spacing(env, path) result(dx)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path
        type(h5_file_t) :: file
        integer :: stat
        dx = 0.0_wp
        call h5_open_read(env, path, file, stat)
        if (stat == 0) then
            dx = file_spacing(file)
            call h5_close(file)
        end if
        ! one answer on every rank (the smallest: a rank that could not read it says so),
        ! since the callers branch into collective reads on it
        dx = -global_max(env, -dx)
    end function stored_spacing

    !> The attribute 'dx' of an open file: 0 when it has none, -1 when it is no spacing (not
    !> finite, not positive, unreadable). No comparison with a NaN: it traps where
    !> floating-point exceptions do.
    real(wp) function file_spacing(file) result(dx)
        type(h5_file_t), intent(in) :: file
        integer :: stat
        dx = 0.0_wp
        if (.not. h5_attribute_exists(file, 'dx')) return
        call h5_read_attribute(file, 'dx', dx, stat)
        if (stat /= 0 .or. .not. ieee_is_finite(dx)) dx = -1.0_wp
        if (dx <= 0.0_wp) dx = -1.0_wp
    end function file_spacing

    !> The newest complete checkpoint of `case_name` in `directory` (collective). Incomplete
    !> or unreadable candidates are skipped and named in `skipped`.
    subroutine find_latest_checkpoint(env, directory, case_name, path, skipped, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: directory, case_name
        character(len=:), allocatable, intent(out) :: path, skipped, errmsg
        integer, intent(out) :: stat
        character(len=:), allocatable :: prefix, candidate, text, reason
        integer(i8), allocatable :: steps(:)
        character(len=512), allocatable :: names(:)
        integer :: best, dim
        integer(i8) :: step, rows
        real(wp) :: time

        path = ''
        skipped = ''
        errmsg = ''
        call checkpoint_names(env, directory, case_name, names, steps, stat)
        if (stat /= 0) then
            errmsg = "cannot read the directory '" // directory // "'"
            return
        end if
        prefix = trim(case_name) // '_checkpoint_'
        stat = 1
        do while (size(steps) > 0)
            best = maxloc(steps, dim=1)
            candidate = trim(directory) // '/' // trim(names(best))
            call read_snapshot_header(env, candidate, time, step, dim, rows, text, stat, reason)
            if (stat == 0) then
                path = candidate
                return
            end if
            ! (one reason after another, separated: they ran together)
            if (len(skipped) > 0) skipped = skipped // ';'
            skipped = skipped // ' ' // reason
            steps(best) = -1
            if (all(steps < 0)) exit
        end do
        stat = 1
        errmsg = "no complete checkpoint '" // prefix // "*.h5' in '" // directory // "'"
        if (len(skipped) > 0) errmsg = errmsg // ' (skipped:' // skipped // ')'
    end subroutine find_latest_checkpoint

    !> Whether `directory` holds a checkpoint of `case_name` (a file named as one, complete or
    !> not; collective); stat /= 0 when it cannot be listed (the caller tells a missing
    !> directory, which holds none, from an unreadable one).
    subroutine has_checkpoint(env, directory, case_name, found, stat)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: directory, case_name
        logical, intent(out) :: found
        integer, intent(out) :: stat
        character(len=512), allocatable :: names(:)
        integer(i8), allocatable :: steps(:)
        call checkpoint_names(env, directory, case_name, names, steps, stat)
        found = .false.
        if (stat == 0) found = size(names) > 0
    end subroutine has_checkpoint

    !> The files of `directory` named as checkpoints of `case_name` and their steps
    !> (<case>_checkpoint_<step>.h5), in the listing's order; stat /= 0 when the directory
    !> cannot be read (collective: rank 0 lists it).
    subroutine checkpoint_names(env, directory, case_name, names, steps, stat)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: directory, case_name
        character(len=512), allocatable, intent(out) :: names(:)
        integer(i8), allocatable, intent(out) :: steps(:)
        integer, intent(out) :: stat
        character(len=:), allocatable :: listing, prefix, name
        integer :: k, start, n, digits_stat
        integer(i8) :: step
        allocate(names(0), steps(0))
        listing = ''
        if (env%rank == 0) then
            call list_directory(directory, listing, stat)
            if (stat /= 0) listing = achar(0)
        end if
        call broadcast_text(env, listing)
        stat = 0
        if (listing == achar(0)) then
            stat = 1
            return
        end if
        prefix = trim(case_name) // '_checkpoint_'
        start = 1
        do k = 1, len(listing)
            if (listing(k:k) /= new_line('a')) cycle
            name = listing(start:k - 1)
            start = k + 1
            n = len(name)
            if (n <= len(prefix) + 3) cycle
            if (name(1:len(prefix)) /= prefix .or. name(n - 2:n) /= '.h5') cycle
            ! digits only, as the files of a case are told apart elsewhere
            ! (sph_earlier_output): a list-directed read took '12 old', '+5' or '2*5'
            if (verify(name(len(prefix) + 1:n - 3), '0123456789') /= 0) cycle
            read(name(len(prefix) + 1:n - 3), *, iostat=digits_stat) step
            if (digits_stat /= 0) cycle
            names = [character(len=512) :: names, name]
            steps = [steps, step]
        end do
    end subroutine checkpoint_names
end module sph_checkpoint
