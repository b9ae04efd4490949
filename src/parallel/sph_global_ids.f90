!> Global particle ids for particles created in parallel (remeshing: 2^dim children per
!> parent, midpoints of pairs): unique, larger than every existing id, and independent of
!> the number of ranks and of the storage order. Each new particle carries a key that is
!> unique across all ranks (for instance its parent's id and a child slot); its id is
!> base + 1 + the 0-based rank of its key in the global lexicographic order of all keys.
!> The global rank is found by a parallel sample sort (no rank ever holds all keys):
!>  1. sort the local keys; take a regular sample, proportional to each rank's count;
!>  2. gather the samples (MPI_Allgatherv), sort them, pick nranks - 1 splitters;
!>  3. send every key to its bucket (MPI_Alltoallv); sort the bucket;
!>  4. the bucket's offset is the exclusive scan of bucket sizes;
!>  5. send the ids back along the same route (MPI_Alltoallv, counts swapped).
module sph_global_ids
    use mpi_f08
    use sph_kinds, only: i8
    use sph_key_sort, only: sort_by_keys, id_order   ! id_order: re-exported (serial)
    use sph_errors, only: check_mpi, fatal_abort
    use sph_mpi_env, only: mpi_env_t, mpi_i8, global_max, global_sum, exclusive_scan_i8
    implicit none
    private
    public :: global_max_id, assign_global_ids, find_duplicate_ids, id_order

    !> samples per rank on average: more samples, better balanced buckets
    integer, parameter :: oversampling = 32

contains

    !> Largest of ids(1:n) over all ranks, 0 if no rank has any (ids are positive).
    !> Collective; n may be 0 on any rank.
    integer(i8) function global_max_id(env, ids, n)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: ids(:)
        integer, intent(in) :: n
        integer(i8) :: local
        local = 0_i8
        if (n > 0) local = max(0_i8, maxval(ids(1:n)))
        global_max_id = global_max(env, local)
    end function global_max_id

    !> ids(i) = base + 1 + (0-based rank of keys(:, i) in the lexicographic order of the keys
    !> of all ranks); next_base = base + number of keys over all ranks. keys(2, n) must be
    !> unique across all ranks (a duplicate aborts) and base the same on every rank.
    !> Collective; n may be 0 on any rank. Local work O(n log n + P log P) for P ranks.
    subroutine assign_global_ids(env, keys, n, base, ids, next_base)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: keys(:, :)
        integer, intent(in) :: n
        integer(i8), intent(in) :: base
        integer(i8), intent(out) :: ids(:)
        integer(i8), intent(out) :: next_base
        integer :: nranks, i, j, b, m, n_samples, n_all_samples, n_bucket, ierr
        integer(i8) :: n_global, offset
        integer, allocatable :: perm(:), bucket_perm(:), sample_perm(:)
        integer, allocatable :: sample_counts(:), sample_displs(:)
        integer, allocatable :: send_counts(:), send_displs(:), recv_counts(:), recv_displs(:)
        integer(i8), allocatable :: sorted(:, :), samples(:, :), all_samples(:, :)
        integer(i8), allocatable :: splitters(:, :), bucket(:, :), bucket_ids(:), back(:)

        nranks = env%nranks
        n_global = global_sum(env, int(n, i8))
        next_base = base + n_global
        if (n_global == 0) return

        ! 1. local sort and a sample proportional to the local count
        allocate(perm(max(n, 1)), sorted(2, max(n, 1)))
        call sort_keys(keys, n, perm)
        do i = 1, n
            sorted(:, i) = keys(:, perm(i))
        end do
        n_samples = 0
        if (n > 0) n_samples = int(min(int(n, i8), &
            (int(oversampling, i8) * nranks * n + n_global - 1) / n_global))
        allocate(samples(2, max(n_samples, 1)))
        do j = 1, n_samples
            ! midpoint of the j-th of n_samples equal slices of the sorted local keys
            samples(:, j) = sorted(:, int(((2_i8 * j - 1) * n) / (2_i8 * n_samples)) + 1)
        end do

        ! 2. every rank gets all samples and picks the same splitters
        allocate(sample_counts(nranks), sample_displs(nranks))
        call MPI_Allgather(2 * n_samples, 1, MPI_INTEGER, sample_counts, 1, MPI_INTEGER, &
            env%comm, ierr)
        call check_mpi(ierr, 'assign_global_ids samples count')
        sample_displs(1) = 0
        do b = 2, nranks
            sample_displs(b) = sample_displs(b - 1) + sample_counts(b - 1)
        end do
        n_all_samples = (sample_displs(nranks) + sample_counts(nranks)) / 2
        allocate(all_samples(2, n_all_samples), sample_perm(n_all_samples))
        call MPI_Allgatherv(samples, 2 * n_samples, mpi_i8, all_samples, sample_counts, &
            sample_displs, mpi_i8, env%comm, ierr)
        call check_mpi(ierr, 'assign_global_ids samples')
        call sort_keys(all_samples, n_all_samples, sample_perm)
        ! splitters(:, b) is the smallest key of bucket b (b = 1 .. nranks - 1; bucket 0
        ! starts at minus infinity)
        allocate(splitters(2, max(nranks - 1, 1)))
        do b = 1, nranks - 1
            splitters(:, b) = all_samples(:, sample_perm((b * n_all_samples) / nranks + 1))
        end do

        ! 3. sorted keys fall into consecutive runs, one per bucket
        allocate(send_counts(nranks), send_displs(nranks), recv_counts(nranks), &
            recv_displs(nranks))
        send_counts = 0
        b = 0
        do i = 1, n
            do while (b < nranks - 1)
                if (key_less(sorted(:, i), splitters(:, b + 1))) exit
                b = b + 1
            end do
            send_counts(b + 1) = send_counts(b + 1) + 1
        end do
        call MPI_Alltoall(send_counts, 1, MPI_INTEGER, recv_counts, 1, MPI_INTEGER, &
            env%comm, ierr)
        call check_mpi(ierr, 'assign_global_ids counts')
        send_displs(1) = 0
        recv_displs(1) = 0
        do b = 2, nranks
            send_displs(b) = send_displs(b - 1) + send_counts(b - 1)
            recv_displs(b) = recv_displs(b - 1) + recv_counts(b - 1)
        end do
        n_bucket = recv_displs(nranks) + recv_counts(nranks)
        allocate(bucket(2, max(n_bucket, 1)), bucket_perm(max(n_bucket, 1)))
        call MPI_Alltoallv(sorted, 2 * send_counts, 2 * send_displs, mpi_i8, bucket, &
            2 * recv_counts, 2 * recv_displs, mpi_i8, env%comm, ierr)
        call check_mpi(ierr, 'assign_global_ids keys')
        call sort_keys(bucket, n_bucket, bucket_perm)
        do m = 2, n_bucket
            if (.not. key_less(bucket(:, bucket_perm(m - 1)), bucket(:, bucket_perm(m)))) then
                call fatal_abort('assign_global_ids', 'the same key was given twice')
            end if
        end do

        ! 4. ids of the bucket, in the order the keys arrived
        offset = exclusive_scan_i8(env, int(n_bucket, i8))
        allocate(bucket_ids(max(n_bucket, 1)))
        do m = 1, n_bucket
            bucket_ids(bucket_perm(m)) = base + offset + int(m, i8)
        end do

        ! 5. back to the ranks the keys came from, in the order they were sent
        allocate(back(max(n, 1)))
        call MPI_Alltoallv(bucket_ids, recv_counts, recv_displs, mpi_i8, back, send_counts, &
            send_displs, mpi_i8, env%comm, ierr)
        call check_mpi(ierr, 'assign_global_ids ids')
        do i = 1, n
            ids(perm(i)) = back(i)
        end do
    end subroutine assign_global_ids

    !> How many distinct ids occur more than once in ids(1:n) over all ranks, and the
    !> smallest of them (0 when none). Each id goes to rank modulo(id, nranks), which sorts
    !> what it receives. Collective; n may be 0 on any rank.
    subroutine find_duplicate_ids(env, ids, n, n_duplicates, smallest)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: ids(:)
        integer, intent(in) :: n
        integer(i8), intent(out) :: n_duplicates, smallest
        integer, allocatable :: send_counts(:), send_displs(:), recv_counts(:), recv_displs(:)
        integer, allocatable :: fill(:), perm(:)
        integer(i8), allocatable :: outgoing(:), received(:), incoming(:, :)
        integer :: i, b, m, n_in, ierr, nranks
        integer(i8) :: local_count, local_smallest
        nranks = env%nranks
        allocate(send_counts(nranks), send_displs(nranks), recv_counts(nranks), &
            recv_displs(nranks), fill(nranks), outgoing(max(n, 1)))
        send_counts = 0
        do i = 1, n
            b = int(modulo(ids(i), int(nranks, i8))) + 1
            send_counts(b) = send_counts(b) + 1
        end do
        call MPI_Alltoall(send_counts, 1, MPI_INTEGER, recv_counts, 1, MPI_INTEGER, &
            env%comm, ierr)
        call check_mpi(ierr, 'find_duplicate_ids counts')
        send_displs(1) = 0
        recv_displs(1) = 0
        do b = 2, nranks
            send_displs(b) = send_displs(b - 1) + send_counts(b - 1)
            recv_displs(b) = recv_displs(b - 1) + recv_counts(b - 1)
        end do
        fill = send_displs
        do i = 1, n
            b = int(modulo(ids(i), int(nranks, i8))) + 1
            fill(b) = fill(b) + 1
            outgoing(fill(b)) = ids(i)
        end do
        n_in = recv_displs(nranks) + recv_counts(nranks)
        allocate(received(max(n_in, 1)), incoming(2, max(n_in, 1)), perm(max(n_in, 1)))
        call MPI_Alltoallv(outgoing, send_counts, send_displs, mpi_i8, received, &
            recv_counts, recv_displs, mpi_i8, env%comm, ierr)
        call check_mpi(ierr, 'find_duplicate_ids ids')
        incoming = 0
        incoming(1, 1:n_in) = received(1:n_in)
        call sort_keys(incoming, n_in, perm)
        local_count = 0
        local_smallest = huge(1_i8)
        do m = 2, n_in
            if (incoming(1, perm(m)) /= incoming(1, perm(m - 1))) cycle
            if (m > 2) then
                if (incoming(1, perm(m - 2)) == incoming(1, perm(m))) cycle   ! counted
            end if
            local_count = local_count + 1
            local_smallest = min(local_smallest, incoming(1, perm(m)))
        end do
        n_duplicates = global_sum(env, local_count)
        smallest = -global_max(env, -local_smallest)
        if (n_duplicates == 0) smallest = 0
    end subroutine find_duplicate_ids

    !> Lexicographic order of key pairs.
    pure logical function key_less(a, b)
        integer(i8), intent(in) :: a(2), b(2)
        key_less = a(1) < b(1) .or. (a(1) == b(1) .and. a(2) < b(2))
    end function key_less

    !> perm(1:n) such that keys(:, perm(1:n)) is in increasing lexicographic order (stable).
    subroutine sort_keys(keys, n, perm)
        integer(i8), intent(in) :: keys(:, :)
        integer, intent(in) :: n
        integer, intent(out) :: perm(:)
        integer :: i
        perm(1:n) = [(i, i = 1, n)]
        call sort_by_keys(keys(:, 1:n), perm(1:n))
    end subroutine sort_keys
end module sph_global_ids
