!> The project communicator and the thin wrapper for reductions and broadcasts that the rest
!> of the code uses instead of calling MPI directly.
module sph_mpi_env
    use mpi_f08
    use sph_kinds, only: wp, i8
    use sph_errors, only: check_mpi, set_error_comm
    implicit none
    private
    public :: mpi_env_t, mpi_env_init_world, mpi_env_from_comm, mpi_env_free, mpi_env_split
    public :: global_sum, global_max, global_min, broadcast_text, exclusive_scan_i8
    public :: mpi_wp, mpi_i8, agreed_status, ranks_on_node, rank0_flag

    type(MPI_Datatype), parameter :: mpi_wp = MPI_DOUBLE_PRECISION  !< matches sph_kinds%wp
    type(MPI_Datatype), parameter :: mpi_i8 = MPI_INTEGER8          !< matches sph_kinds%i8

    !> A communicator and this process's place in it.
    type :: mpi_env_t
        type(MPI_Comm) :: comm
        integer :: rank = 0
        integer :: nranks = 1
        logical :: owns_comm = .false.
    end type mpi_env_t

    interface global_sum
        module procedure global_sum_wp, global_sum_i8, global_sum_wp_array, global_sum_i8_array
    end interface
    interface global_max
        module procedure global_max_wp, global_max_i8, global_max_wp_array
    end interface
    interface global_min
        module procedure global_min_wp
    end interface

contains

    !> Initialise MPI and duplicate the world communicator into the project communicator.
    subroutine mpi_env_init_world(env)
        type(mpi_env_t), intent(out) :: env
        integer :: ierr
        logical :: initialized
        call MPI_Initialized(initialized, ierr)
        if (.not. initialized) then
            call MPI_Init(ierr)
            call check_mpi(ierr, 'mpi_env_init_world')
        end if
        call MPI_Comm_dup(MPI_COMM_WORLD, env%comm, ierr)
        call check_mpi(ierr, 'mpi_env_init_world')
        env%owns_comm = .true.
        call fill_rank(env)
        call set_error_comm(env%comm)
    end subroutine mpi_env_init_world

    !> Wrap a communicator handed in by the caller (tests use their sub-communicators).
    subroutine mpi_env_from_comm(env, comm)
        type(mpi_env_t), intent(out) :: env
        type(MPI_Comm), intent(in) :: comm
        integer :: ierr
        call MPI_Comm_dup(comm, env%comm, ierr)
        call check_mpi(ierr, 'mpi_env_from_comm')
        env%owns_comm = .true.
        call fill_rank(env)
    end subroutine mpi_env_from_comm

    !> Ranks with the same colour form a new environment; colour < 0 gets none (member false).
    subroutine mpi_env_split(env, colour, sub, member)
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: colour
        type(mpi_env_t), intent(out) :: sub
        logical, intent(out) :: member
        integer :: ierr
        if (colour >= 0) then
            call MPI_Comm_split(env%comm, colour, env%rank, sub%comm, ierr)
        else
            call MPI_Comm_split(env%comm, MPI_UNDEFINED, env%rank, sub%comm, ierr)
        end if
        call check_mpi(ierr, 'mpi_env_split')
        member = colour >= 0
        if (member) then
            sub%owns_comm = .true.
            call fill_rank(sub)
        end if
    end subroutine mpi_env_split

    subroutine fill_rank(env)
        type(mpi_env_t), intent(inout) :: env
        integer :: ierr
        call MPI_Comm_rank(env%comm, env%rank, ierr)
        call check_mpi(ierr, 'mpi_env rank')
        call MPI_Comm_size(env%comm, env%nranks, ierr)
        call check_mpi(ierr, 'mpi_env size')
    end subroutine fill_rank

    !> How many ranks of env share this rank's node (its shared-memory domain): the ranks
    !> among which the node's memory is divided (collective).
    integer function ranks_on_node(env) result(n)
        type(mpi_env_t), intent(in) :: env
        type(MPI_Comm) :: node
        integer :: ierr
        call MPI_Comm_split_type(env%comm, MPI_COMM_TYPE_SHARED, env%rank, MPI_INFO_NULL, &
            node, ierr)
        call check_mpi(ierr, 'ranks_on_node split')
        call MPI_Comm_size(node, n, ierr)
        call check_mpi(ierr, 'ranks_on_node size')
        call MPI_Comm_free(node, ierr)
        call check_mpi(ierr, 'ranks_on_node free')
    end function ranks_on_node

    !> Free the communicator if the environment owns it (a split), not MPI_COMM_WORLD.
    subroutine mpi_env_free(env)
        type(mpi_env_t), intent(inout) :: env
        integer :: ierr
        if (env%owns_comm) then
            call MPI_Comm_free(env%comm, ierr)
            call check_mpi(ierr, 'mpi_env_free')
            env%owns_comm = .false.
        end if
    end subroutine mpi_env_free

    function global_sum_wp(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in) :: x
        real(wp) :: s
        integer :: ierr
        call MPI_Allreduce(x, s, 1, mpi_wp, MPI_SUM, env%comm, ierr)
        call check_mpi(ierr, 'global_sum')
    end function global_sum_wp

    function global_sum_i8(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: x
        integer(i8) :: s
        integer :: ierr
        call MPI_Allreduce(x, s, 1, mpi_i8, MPI_SUM, env%comm, ierr)
        call check_mpi(ierr, 'global_sum')
    end function global_sum_i8

    function global_sum_wp_array(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in) :: x(:)
        real(wp) :: s(size(x))
        integer :: ierr
        call MPI_Allreduce(x, s, size(x), mpi_wp, MPI_SUM, env%comm, ierr)
        call check_mpi(ierr, 'global_sum')
    end function global_sum_wp_array

    function global_sum_i8_array(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: x(:)
        integer(i8) :: s(size(x))
        integer :: ierr
        call MPI_Allreduce(x, s, size(x), mpi_i8, MPI_SUM, env%comm, ierr)
        call check_mpi(ierr, 'global_sum')
    end function global_sum_i8_array

    function global_max_wp(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in) :: x
        real(wp) :: s
        integer :: ierr
        call MPI_Allreduce(x, s, 1, mpi_wp, MPI_MAX, env%comm, ierr)
        call check_mpi(ierr, 'global_max')
    end function global_max_wp

    !> Element-wise maxima over all ranks in one reduction.
    function global_max_wp_array(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in) :: x(:)
        real(wp) :: s(size(x))
        integer :: ierr
        call MPI_Allreduce(x, s, size(x), mpi_wp, MPI_MAX, env%comm, ierr)
        call check_mpi(ierr, 'global_max')
    end function global_max_wp_array

    function global_max_i8(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: x
        integer(i8) :: s
        integer :: ierr
        call MPI_Allreduce(x, s, 1, mpi_i8, MPI_MAX, env%comm, ierr)
        call check_mpi(ierr, 'global_max')
    end function global_max_i8

    function global_min_wp(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in) :: x
        real(wp) :: s
        integer :: ierr
        call MPI_Allreduce(x, s, 1, mpi_wp, MPI_MIN, env%comm, ierr)
        call check_mpi(ierr, 'global_min')
    end function global_min_wp

    !> Exclusive prefix sum (rank 0 gets 0): offsets of each rank's rows in a global dataset.
    function exclusive_scan_i8(env, x) result(s)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: x
        integer(i8) :: s
        integer :: ierr
        call MPI_Exscan(x, s, 1, mpi_i8, MPI_SUM, env%comm, ierr)
        call check_mpi(ierr, 'exclusive_scan')
        if (env%rank == 0) s = 0
    end function exclusive_scan_i8

    !> Broadcast a deferred-length string from rank 0, or from `root` (its length first).
    subroutine broadcast_text(env, text, root)
        type(mpi_env_t), intent(in) :: env
        character(len=:), allocatable, intent(inout) :: text
        integer, intent(in), optional :: root
        integer :: n, ierr, from
        from = 0
        if (present(root)) from = root
        n = 0
        if (env%rank == from) n = len(text)
        call MPI_Bcast(n, 1, MPI_INTEGER, from, env%comm, ierr)
        call check_mpi(ierr, 'broadcast_text')
        if (env%rank /= from) then
            if (allocated(text)) deallocate(text)
            allocate(character(len=n) :: text)
        end if
        if (n > 0) then
            call MPI_Bcast(text, n, MPI_CHARACTER, from, env%comm, ierr)
            call check_mpi(ierr, 'broadcast_text')
        end if
    end subroutine broadcast_text

    !> Rank 0's flag on every rank (collective). For what each rank would otherwise ask the
    !> file system for itself before a collective step: on a network file system one node's
    !> cached answer (a folder made by the job before, not yet seen there) sent the ranks down
    !> different paths, one of them into a collective call the others never made.
    logical function rank0_flag(env, flag)
        type(mpi_env_t), intent(in) :: env
        logical, intent(in) :: flag
        rank0_flag = global_max(env, merge(1_i8, 0_i8, env%rank == 0 .and. flag)) > 0_i8
    end function rank0_flag

    !> The same status on every rank: the largest (collective).
    integer function agreed_status(env, stat)
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: stat
        agreed_status = int(global_max(env, int(stat, i8)))
    end function agreed_status
end module sph_mpi_env
