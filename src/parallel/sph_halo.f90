!> Halo exchange: ghost copies of every owned particle within `reach` of another subdomain,
!> for other ranks and for this rank's own periodic images alike (a rank can be its own
!> neighbour across a periodic face). Built in two halves (start: counts, post receives and
!> sends; finish: wait and unpack), and refreshed in place (same ghosts, current fields) at
!> the stages of a time step where the physics needs up-to-date neighbours.
module sph_halo
    use mpi_f08
    use sph_kinds, only: wp, i8
    use sph_errors, only: check_mpi, fatal_abort
    use sph_mpi_env, only: mpi_env_t, mpi_wp
    use sph_domain, only: domain_t, far
    use sph_particles, only: particles_t, particles_pack, particles_unpack, particles_reserve, &
        pack_widths, HALO_GHOST
    implicit none
    private
    public :: halo_t, halo_setup, halo_build_start, halo_build_finish, halo_build
    public :: halo_refresh_start, halo_refresh_finish, halo_refresh
    public :: halo_reverse_sum_start, halo_reverse_sum_finish, halo_reverse_sum

    integer, parameter :: tag_count = 101, tag_data = 102, tag_ints = 103
    integer, parameter :: tag_reverse_sum = 104

    type :: halo_t
        real(wp) :: reach = 0.0_wp
        ! (rank, periodic shift) pairs whose region this rank's particles may reach
        integer :: n_partners = 0
        integer, allocatable :: partner_rank(:)
        real(wp), allocatable :: partner_shift(:, :)
        ! distinct ranks exchanged with (symmetric: send to r <=> receive from r)
        integer :: n_peers = 0
        integer, allocatable :: peer_rank(:)
        ! send list, grouped by peer: particle index and shift to apply
        integer, allocatable :: send_count(:), send_offset(:)
        integer, allocatable :: send_index(:)
        real(wp), allocatable :: send_shift(:, :)
        integer, allocatable :: recv_count(:), recv_offset(:)
        ! in-flight exchange: the fields of one stage (mask), reals and integers apart
        integer :: mask = HALO_GHOST
        integer :: n_real = 0, n_int = 0
        real(wp), allocatable :: send_buf(:, :), recv_buf(:, :)
        integer(i8), allocatable :: send_ibuf(:, :), recv_ibuf(:, :)
        type(MPI_Request), allocatable :: requests(:)
        integer :: n_requests = 0
        ! in-flight reverse sum (ghost contributions back to their owners): own buffers and
        ! requests, so a reverse sum and a forward refresh can overlap
        real(wp), allocatable :: rsum_send_buf(:), rsum_recv_buf(:)  ! rows of width, packed
        type(MPI_Request), allocatable :: rsum_requests(:)
        integer :: n_rsum_requests = 0
    end type halo_t

contains

    !> Which (rank, shift) regions this rank's particles can reach: recomputed whenever the
    !> decomposition changes. reach = kernel support plus a skin for motion within a step.
    subroutine halo_setup(halo, domain, reach)
        type(halo_t), intent(inout) :: halo
        type(domain_t), intent(in) :: domain
        real(wp), intent(in) :: reach
        integer :: r, sx, sy, sz, n, k, smax(3)
        real(wp) :: shift(3)
        integer, allocatable :: ranks(:)
        real(wp), allocatable :: shifts(:, :)

        halo%reach = reach
        smax = 0
        do k = 1, domain%dim
            if (domain%periodic(k)) smax(k) = 1
        end do
        allocate(ranks(0), shifts(3, 0))
        do r = 0, domain%nranks - 1
            do sz = -smax(3), smax(3)
                do sy = -smax(2), smax(2)
                    do sx = -smax(1), smax(1)
                        if (r == domain%rank .and. sx == 0 .and. sy == 0 .and. sz == 0) cycle
                        shift = [sx, sy, sz] * domain%length
                        if (boxes_touch(domain%box_lo(:, domain%rank) + shift, &
                                        domain%box_hi(:, domain%rank) + shift, &
                                        domain%box_lo(:, r) - reach, domain%box_hi(:, &
                                            r) + reach)) then
                            ranks = [ranks, r]
                            shifts = reshape([shifts, shift], [3, size(ranks)])
                        end if
                    end do
                end do
            end do
        end do
        halo%n_partners = size(ranks)
        call move_alloc(ranks, halo%partner_rank)
        call move_alloc(shifts, halo%partner_shift)
        ! distinct peers in rank order
        if (allocated(halo%peer_rank)) deallocate(halo%peer_rank)
        allocate(halo%peer_rank(0))
        do r = 0, domain%nranks - 1
            if (any(halo%partner_rank == r)) halo%peer_rank = [halo%peer_rank, r]
        end do
        n = size(halo%peer_rank)
        halo%n_peers = n
        if (allocated(halo%send_count)) deallocate(halo%send_count, halo%send_offset, &
            halo%recv_count, halo%recv_offset)
        allocate(halo%send_count(n), halo%send_offset(n + 1), halo%recv_count(n), &
            halo%recv_offset(n + 1))
        if (allocated(halo%requests)) deallocate(halo%requests)
        allocate(halo%requests(4 * n))   ! reals and integers, each way
    end subroutine halo_setup

    pure logical function boxes_touch(alo, ahi, blo, bhi)
        real(wp), intent(in) :: alo(3), ahi(3), blo(3), bhi(3)
        boxes_touch = all(alo <= bhi .and. blo <= ahi)
    end function boxes_touch

    !> Select ghosts among the owned particles and exchange counts, then post the data.
    subroutine halo_build_start(halo, domain, env, p, reach_of)
        type(halo_t), intent(inout) :: halo
        type(domain_t), intent(in) :: domain
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        !> per owned particle, a reach of its own (at most halo%reach): it becomes a ghost
        !> only of the regions within it
        real(wp), intent(in), optional :: reach_of(:)
        integer :: i, k, q, peer, total, ierr
        integer, allocatable :: fill(:), peer_of_partner(:)
        real(wp) :: xs(3), lo(3), hi(3), inner_lo(3), inner_hi(3)

        p%n_ghost = 0
        p%n_total = p%n_owned
        allocate(peer_of_partner(halo%n_partners))
        do k = 1, halo%n_partners
            peer_of_partner(k) = findloc(halo%peer_rank, halo%partner_rank(k), dim=1)
        end do
        ! pass 1: count, pass 2: fill (kept in peer order so the receiver's slots are stable)
        ! a particle deeper than the reach inside this rank's box reaches no other box and no
        ! periodic image (the boxes tile the domain): most particles skip the partners' tests
        inner_lo = domain%box_lo(:, domain%rank) + halo%reach
        inner_hi = domain%box_hi(:, domain%rank) - halo%reach
        halo%send_count = 0
        do i = 1, p%n_owned
            if (deep(i)) cycle
            do k = 1, halo%n_partners
                if (reaches(i, k)) then
                    q = peer_of_partner(k)
                    halo%send_count(q) = halo%send_count(q) + 1
                end if
            end do
        end do
        halo%send_offset(1) = 0
        do q = 1, halo%n_peers
            halo%send_offset(q + 1) = halo%send_offset(q) + halo%send_count(q)
        end do
        total = halo%send_offset(halo%n_peers + 1)
        if (allocated(halo%send_index)) then
            if (size(halo%send_index) < total) deallocate(halo%send_index, halo%send_shift)
        end if
        if (.not. allocated(halo%send_index)) allocate(halo%send_index(max(total, 1)), &
            halo%send_shift(3, max(total, 1)))
        allocate(fill(halo%n_peers))
        fill = halo%send_offset(1:halo%n_peers)
        do i = 1, p%n_owned
            if (deep(i)) cycle
            do k = 1, halo%n_partners
                if (reaches(i, k)) then
                    q = peer_of_partner(k)
                    fill(q) = fill(q) + 1
                    halo%send_index(fill(q)) = i
                    halo%send_shift(:, fill(q)) = halo%partner_shift(:, k)
                end if
            end do
        end do
        ! counts: small blocking exchange, the receiver needs them to size its slots
        halo%n_requests = 0
        do q = 1, halo%n_peers
            peer = halo%peer_rank(q)
            halo%n_requests = halo%n_requests + 1
            call MPI_Irecv(halo%recv_count(q), 1, MPI_INTEGER, peer, tag_count, env%comm, &
                halo%requests(halo%n_requests), ierr)
            call check_mpi(ierr, 'halo counts irecv')
        end do
        do q = 1, halo%n_peers
            peer = halo%peer_rank(q)
            halo%n_requests = halo%n_requests + 1
            call MPI_Isend(halo%send_count(q), 1, MPI_INTEGER, peer, tag_count, env%comm, &
                halo%requests(halo%n_requests), ierr)
            call check_mpi(ierr, 'halo counts isend')
        end do
        call MPI_Waitall(halo%n_requests, halo%requests, MPI_STATUSES_IGNORE, ierr)
        call check_mpi(ierr, 'halo counts wait')
        halo%recv_offset(1) = 0
        do q = 1, halo%n_peers
            halo%recv_offset(q + 1) = halo%recv_offset(q) + halo%recv_count(q)
        end do
        call post_data(halo, env, p, HALO_GHOST)
    contains
        logical function deep(ii)
            integer, intent(in) :: ii
            deep = all(p%x(1:domain%dim, ii) > inner_lo(1:domain%dim) .and. &
                p%x(1:domain%dim, ii) < inner_hi(1:domain%dim))
        end function deep

        logical function reaches(ii, kk)
            integer, intent(in) :: ii, kk
            integer :: r
            r = halo%partner_rank(kk)
            xs = p%x(:, ii) + halo%partner_shift(:, kk)
            if (present(reach_of)) then
                lo = domain%box_lo(:, r) - min(reach_of(ii), halo%reach)
                hi = domain%box_hi(:, r) + min(reach_of(ii), halo%reach)
            else
                lo = domain%box_lo(:, r) - halo%reach
                hi = domain%box_hi(:, r) + halo%reach
            end if
            reaches = all(xs(1:domain%dim) >= lo(1:domain%dim) .and. &
                xs(1:domain%dim) <= hi(1:domain%dim))
            if (reaches .and. r == domain%rank) then
                ! an image in this rank's own region but outside its box is still a ghost;
                ! the image of a particle onto itself (zero shift) never is
                reaches = any(abs(halo%partner_shift(:, kk)) > 0.0_wp)
            end if
        end function reaches
    end subroutine halo_build_start

    !> Pack the send list with the fields of `mask` (shift applied to positions) and post the
    !> receives and sends: reals and integers travel in separate messages.
    subroutine post_data(halo, env, p, mask)
        type(halo_t), intent(inout) :: halo
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask
        integer :: q, n_send, n_recv, ierr, peer
        n_send = halo%send_offset(halo%n_peers + 1)
        n_recv = halo%recv_offset(halo%n_peers + 1)
        halo%mask = mask
        call pack_widths(p, mask, halo%n_real, halo%n_int)
        call ensure_buffer(halo%send_buf, halo%n_real, n_send)
        call ensure_buffer(halo%recv_buf, halo%n_real, n_recv)
        call ensure_int_buffer(halo%send_ibuf, halo%n_int, n_send)
        call ensure_int_buffer(halo%recv_ibuf, halo%n_int, n_recv)
        call particles_pack(p, mask, halo%send_index, n_send, halo%send_buf, halo%send_ibuf, &
            halo%send_shift)
        halo%n_requests = 0
        do q = 1, halo%n_peers
            if (halo%recv_count(q) == 0) cycle
            peer = halo%peer_rank(q)
            if (halo%n_real > 0) then
                halo%n_requests = halo%n_requests + 1
                call MPI_Irecv(halo%recv_buf(1, halo%recv_offset(q) + 1), &
                    halo%n_real * halo%recv_count(q), mpi_wp, peer, tag_data, env%comm, &
                    halo%requests(halo%n_requests), ierr)
                call check_mpi(ierr, 'halo data irecv')
            end if
            if (halo%n_int > 0) then
                halo%n_requests = halo%n_requests + 1
                call MPI_Irecv(halo%recv_ibuf(1, halo%recv_offset(q) + 1), &
                    halo%n_int * halo%recv_count(q), MPI_INTEGER8, peer, tag_ints, env%comm, &
                    halo%requests(halo%n_requests), ierr)
                call check_mpi(ierr, 'halo integers irecv')
            end if
        end do
        do q = 1, halo%n_peers
            if (halo%send_count(q) == 0) cycle
            peer = halo%peer_rank(q)
            if (halo%n_real > 0) then
                halo%n_requests = halo%n_requests + 1
                call MPI_Isend(halo%send_buf(1, halo%send_offset(q) + 1), &
                    halo%n_real * halo%send_count(q), mpi_wp, peer, tag_data, env%comm, &
                    halo%requests(halo%n_requests), ierr)
                call check_mpi(ierr, 'halo data isend')
            end if
            if (halo%n_int > 0) then
                halo%n_requests = halo%n_requests + 1
                call MPI_Isend(halo%send_ibuf(1, halo%send_offset(q) + 1), &
                    halo%n_int * halo%send_count(q), MPI_INTEGER8, peer, tag_ints, env%comm, &
                    halo%requests(halo%n_requests), ierr)
                call check_mpi(ierr, 'halo integers isend')
            end if
        end do
    end subroutine post_data

    !> A (rows, columns) buffer with at least these sizes (reused while large enough).
    subroutine ensure_buffer(buffer, rows, columns)
        real(wp), allocatable, intent(inout) :: buffer(:, :)
        integer, intent(in) :: rows, columns
        if (allocated(buffer)) then
            if (size(buffer, 1) == max(rows, 1) .and. size(buffer, 2) >= columns) return
            deallocate(buffer)
        end if
        allocate(buffer(max(rows, 1), max(columns, 1)))
    end subroutine ensure_buffer

    subroutine ensure_int_buffer(buffer, rows, columns)
        integer(i8), allocatable, intent(inout) :: buffer(:, :)
        integer, intent(in) :: rows, columns
        if (allocated(buffer)) then
            if (size(buffer, 1) == max(rows, 1) .and. size(buffer, 2) >= columns) return
            deallocate(buffer)
        end if
        allocate(buffer(max(rows, 1), max(columns, 1)))
    end subroutine ensure_int_buffer

    !> Wait for the data and store the ghosts after the owned particles.
    subroutine halo_build_finish(halo, p)
        type(halo_t), intent(inout) :: halo
        type(particles_t), intent(inout) :: p
        integer :: n_recv
        n_recv = halo%recv_offset(halo%n_peers + 1)
        call particles_reserve(p, p%n_owned + n_recv)
        call wait_and_unpack(halo, p)
        p%n_ghost = n_recv
        p%n_total = p%n_owned + n_recv
    end subroutine halo_build_finish

    subroutine wait_and_unpack(halo, p)
        type(halo_t), intent(inout) :: halo
        type(particles_t), intent(inout) :: p
        integer :: ierr
        call MPI_Waitall(halo%n_requests, halo%requests, MPI_STATUSES_IGNORE, ierr)
        call check_mpi(ierr, 'halo data wait')
        halo%n_requests = 0
        call particles_unpack(p, halo%mask, p%n_owned + 1, halo%recv_offset(halo%n_peers + 1), &
            halo%recv_buf, halo%recv_ibuf)
    end subroutine wait_and_unpack

    !> Build the halo from scratch (who sends which particles to whom) and receive the ghosts:
    !> halo_build_start, then the wait.
    subroutine halo_build(halo, domain, env, p, reach_of)
        type(halo_t), intent(inout) :: halo
        type(domain_t), intent(in) :: domain
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        real(wp), intent(in), optional :: reach_of(:)   !< as halo_build_start's
        call halo_build_start(halo, domain, env, p, reach_of)
        call halo_build_finish(halo, p)
    end subroutine halo_build

    !> Same ghosts, current values of the fields of one stage (mask: HALO_MOVE, HALO_DENSITY,
    !> ...; see sph_particles): used within a step, when particles have moved much less than
    !> the skin. Virtual copies beyond the ghosts (mirrors) are dropped.
    subroutine halo_refresh_start(halo, env, p, mask)
        type(halo_t), intent(inout) :: halo
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask
        p%n_total = p%n_owned + p%n_ghost
        call post_data(halo, env, p, mask)
    end subroutine halo_refresh_start

    !> Complete a refresh started by halo_refresh_start: wait and unpack the ghosts' fields.
    subroutine halo_refresh_finish(halo, p)
        type(halo_t), intent(inout) :: halo
        type(particles_t), intent(inout) :: p
        call wait_and_unpack(halo, p)
    end subroutine halo_refresh_finish

    !> Send the owners' current values of the fields in `mask` (HALO_* bits) to their ghosts.
    subroutine halo_refresh(halo, env, p, mask)
        type(halo_t), intent(inout) :: halo
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask
        call halo_refresh_start(halo, env, p, mask)
        call halo_refresh_finish(halo, p)
    end subroutine halo_refresh
    !> Reverse halo ("sum back"): start. values(:, n_owned + 1 : n_owned + n_ghost) hold
    !> contributions accumulated on this rank's ghost slots, in the order the forward
    !> exchange filled them (per peer, halo%recv_offset segments); each row goes back to the
    !> rank that owns the particle and is added there into values(:, halo%send_index(k)) by
    !> halo_reverse_sum_finish. width = size(values, 1) is arbitrary (1 for a scalar, 3 for
    !> a vector); no periodic shift is applied to the summed values. The ghost rows are
    !> copied here, so the caller may reuse them until finish, which zeroes them. Columns
    !> beyond n_owned + n_ghost (mirrors) are not touched. Needs a built halo (halo_build);
    !> every rank of the communicator must call it. One reverse sum at a time per halo (it
    !> may overlap a forward refresh). Buffers are kept in halo and only grow.
    subroutine halo_reverse_sum_start(halo, env, n_owned, values)
        type(halo_t), intent(inout) :: halo
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: n_owned
        real(wp), intent(inout) :: values(:, :)
        integer :: q, k, width, n_ghost, n_back, peer, ierr

        halo%n_rsum_requests = 0
        if (halo%n_peers == 0) return
        width = size(values, 1)
        n_ghost = halo%recv_offset(halo%n_peers + 1)
        n_back = halo%send_offset(halo%n_peers + 1)
        if (size(values, 2) < n_owned + n_ghost) then
            call fatal_abort('halo_reverse_sum_start', &
                'values has fewer columns than owned + ghost particles')
        end if
        call reserve_values(halo%rsum_send_buf, width * n_ghost)
        call reserve_values(halo%rsum_recv_buf, width * n_back)
        if (allocated(halo%rsum_requests)) then
            if (size(halo%rsum_requests) < 2 * halo%n_peers) deallocate(halo%rsum_requests)
        end if
        if (.not. allocated(halo%rsum_requests)) allocate(halo%rsum_requests(2 * halo%n_peers))
        do k = 1, n_ghost
            halo%rsum_send_buf((k - 1) * width + 1:k * width) = values(:, n_owned + k)
        end do
        ! the forward direction backwards: receive what was sent, send what was received
        do q = 1, halo%n_peers
            if (halo%send_count(q) == 0) cycle
            peer = halo%peer_rank(q)
            halo%n_rsum_requests = halo%n_rsum_requests + 1
            call MPI_Irecv(halo%rsum_recv_buf(width * halo%send_offset(q) + 1), &
                width * halo%send_count(q), mpi_wp, peer, tag_reverse_sum, env%comm, &
                halo%rsum_requests(halo%n_rsum_requests), ierr)
            call check_mpi(ierr, 'halo reverse sum irecv')
        end do
        do q = 1, halo%n_peers
            if (halo%recv_count(q) == 0) cycle
            peer = halo%peer_rank(q)
            halo%n_rsum_requests = halo%n_rsum_requests + 1
            call MPI_Isend(halo%rsum_send_buf(width * halo%recv_offset(q) + 1), &
                width * halo%recv_count(q), mpi_wp, peer, tag_reverse_sum, env%comm, &
                halo%rsum_requests(halo%n_rsum_requests), ierr)
            call check_mpi(ierr, 'halo reverse sum isend')
        end do
    end subroutine halo_reverse_sum_start

    !> Reverse halo: finish. Waits, adds every returned row into its owned slot
    !> values(:, halo%send_index(k)) (in send-list order, so the result does not depend on
    !> message timing) and sets the ghost slots n_owned + 1 : n_owned + n_ghost to zero.
    subroutine halo_reverse_sum_finish(halo, n_owned, values)
        type(halo_t), intent(inout) :: halo
        integer, intent(in) :: n_owned
        real(wp), intent(inout) :: values(:, :)
        integer :: k, width, n_ghost, ierr

        if (halo%n_peers == 0) return
        width = size(values, 1)
        call MPI_Waitall(halo%n_rsum_requests, halo%rsum_requests, MPI_STATUSES_IGNORE, ierr)
        call check_mpi(ierr, 'halo reverse sum wait')
        halo%n_rsum_requests = 0
        do k = 1, halo%send_offset(halo%n_peers + 1)
            values(:, halo%send_index(k)) = values(:, halo%send_index(k)) &
                + halo%rsum_recv_buf((k - 1) * width + 1:k * width)
        end do
        n_ghost = halo%recv_offset(halo%n_peers + 1)
        values(:, n_owned + 1:n_owned + n_ghost) = 0.0_wp
    end subroutine halo_reverse_sum_finish

    !> Reverse halo sum in one call (start + finish); see halo_reverse_sum_start.
    subroutine halo_reverse_sum(halo, env, n_owned, values)
        type(halo_t), intent(inout) :: halo
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: n_owned
        real(wp), intent(inout) :: values(:, :)
        call halo_reverse_sum_start(halo, env, n_owned, values)
        call halo_reverse_sum_finish(halo, n_owned, values)
    end subroutine halo_reverse_sum

    !> buffer of at least n (and one) values; reallocated only when it must grow.
    subroutine reserve_values(buffer, n)
        real(wp), allocatable, intent(inout) :: buffer(:)
        integer, intent(in) :: n
        if (allocated(buffer)) then
            if (size(buffer) < n) deallocate(buffer)
        end if
        if (.not. allocated(buffer)) allocate(buffer(max(n, 1)))
    end subroutine reserve_values
end module sph_halo
