! Neighbour search and halo exchange against brute force, on 1 to 4 ranks, in 2D and 3D,
! with periodic faces: random particles are decomposed (ORB), migrated, haloed; then
!  - each rank's ghost set equals the brute-force set of (particle, periodic image) within
!    reach of its subdomain, and
!  - every owned particle's cell-list neighbours equal the brute-force minimum-image set.
module test_sph_neighbours_mpi
    use pfunit
    use mpi_f08, only: MPI_Comm
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_from_comm, mpi_env_free
    use sph_particles, only: particles_t, particles_init, KIND_FLUID
    use sph_domain, only: domain_t, domain_create, domain_partition, domain_owner, &
        migrate_particles
    use sph_halo, only: halo_t, halo_setup, halo_build
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use test_sph_random, only: random_points
    implicit none

contains

    !> Every rank makes the same global set and keeps what the first partition gives it.
    subroutine make_particles(env, domain, dim, n_global, periodic, x_all, p)
        type(mpi_env_t), intent(in) :: env
        type(domain_t), intent(out) :: domain
        integer, intent(in) :: dim, n_global
        logical, intent(in) :: periodic(3)
        real(wp), allocatable, intent(out) :: x_all(:, :)
        type(particles_t), intent(out) :: p
        real(wp) :: lo(3), hi(3)
        integer :: i, n
        lo = [0.0_wp, -1.0_wp, 0.5_wp]
        hi = [2.0_wp, 0.5_wp, 1.7_wp]
        if (dim == 2) then
            lo(3) = 0.0_wp
            hi(3) = 0.0_wp
        end if
        call domain_create(domain, env, dim, lo, hi, periodic)
        call random_points(n_global, dim, lo, hi, 12345_i8, x_all)
        call particles_init(p, n_global, dim)
        n = 0
        do i = 1, n_global
            if (domain_owner(domain, x_all(:, i)) /= env%rank) cycle
            n = n + 1
            p%x(:, n) = x_all(:, i)
            p%id(n) = int(i, i8)
            p%kind(n) = KIND_FLUID
        end do
        p%n_owned = n
        p%n_total = n
        ! balance by count, then send every particle to its new owner
        call domain_partition(domain, env, p%x, p%n_owned)
        call migrate_particles(domain, env, p)
    end subroutine make_particles

    !> Minimum-image displacement on the periodic axes.
    function min_image(domain, d) result(e)
        type(domain_t), intent(in) :: domain
        real(wp), intent(in) :: d(3)
        real(wp) :: e(3)
        integer :: a
        e = d
        do a = 1, domain%dim
            if (domain%periodic(a)) e(a) = e(a) - domain%length(a) * anint(e(a) / domain%length(a))
        end do
    end function min_image

    subroutine check_case(this, dim, periodic)
        class(MpiTestMethod), intent(inout) :: this
        integer, intent(in) :: dim
        logical, intent(in) :: periodic(3)
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(domain_t) :: domain
        type(particles_t) :: p
        type(halo_t) :: halo
        type(neighbour_list_t) :: nl
        real(wp), allocatable :: x_all(:, :)
        real(wp) :: radius, d(3), lo(3), hi(3), xs(3), shift(3)
        integer :: i, j, k, n_global, n_expected, sx, sy, sz, smax(3), a, g
        integer(i8), allocatable :: found(:), expected(:)

        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        n_global = merge(700, 1500, dim == 2)
        radius = merge(0.18_wp, 0.3_wp, dim == 2)
        call make_particles(env, domain, dim, n_global, periodic, x_all, p)
        call halo_setup(halo, domain, radius)
        call halo_build(halo, domain, env, p)

        ! ghosts: brute force over all particles and images
        smax = 0
        do a = 1, dim
            if (periodic(a)) smax(a) = 1
        end do
        allocate(expected(0))
        lo = domain%box_lo(:, env%rank) - radius
        hi = domain%box_hi(:, env%rank) + radius
        do i = 1, n_global
            do sz = -smax(3), smax(3)
                do sy = -smax(2), smax(2)
                    do sx = -smax(1), smax(1)
                        shift = [sx, sy, sz] * domain%length
                        xs = x_all(:, i) + shift
                        if (.not. all(xs(1:dim) >= lo(1:dim) .and. xs(1:dim) <= hi(1:dim))) cycle
                        if (sx == 0 .and. sy == 0 .and. sz == 0 .and. &
                            domain_owner(domain, x_all(:, i)) == env%rank) cycle
                        expected = [expected, image_key(int(i, i8), sx, sy, sz)]
                    end do
                end do
            end do
        end do
        allocate(found(p%n_ghost))
        do g = 1, p%n_ghost
            k = p%n_owned + g
            shift = anint((p%x(:, k) - x_all(:, p%id(k))) / max(domain%length, 1.0e-300_wp))
            found(g) = image_key(p%id(k), nint(shift(1)), nint(shift(2)), nint(shift(3)))
        end do
        call sort_i8(expected)
        call sort_i8(found)
#line 120 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
  call assertEqual(size(expected), size(found), 'ghost count equals brute force', &
 & location=SourceLocation( &
 & 'test_sph_neighbours_mpi.pf', &
 & 120) )
  if (anyExceptions()) return
#line 121 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
        if (size(expected) == size(found)) then
#line 122 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
  call assertTrue(all(expected == found), 'ghost set equals brute force (ids and images)', &
 & location=SourceLocation( &
 & 'test_sph_neighbours_mpi.pf', &
 & 122) )
  if (anyExceptions()) return
#line 123 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
        end if

        ! neighbours of every owned particle
        call build_neighbour_list(p%x, p%n_total, p%n_owned, dim, radius, nl)
        do i = 1, p%n_owned
            deallocate(expected, found)
            allocate(expected(0))
            do j = 1, n_global
                if (int(j, i8) == p%id(i)) cycle
                d = min_image(domain, p%x(:, i) - x_all(:, j))
                if (sum(d * d) < radius * radius) expected = [expected, int(j, i8)]
            end do
            n_expected = size(expected)
            allocate(found(nl%start(i + 1) - nl%start(i)))
            found = p%id(nl%index(nl%start(i):nl%start(i + 1) - 1))
            call sort_i8(expected)
            call sort_i8(found)
#line 140 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
  call assertEqual(n_expected, size(found), 'neighbour count equals brute force', &
 & location=SourceLocation( &
 & 'test_sph_neighbours_mpi.pf', &
 & 140) )
  if (anyExceptions()) return
#line 141 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
            if (n_expected /= size(found)) exit
#line 142 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
  call assertTrue(all(expected == found), 'neighbour ids equal brute force', &
 & location=SourceLocation( &
 & 'test_sph_neighbours_mpi.pf', &
 & 142) )
  if (anyExceptions()) return
#line 143 "/work/main/tests/unit/test_sph_neighbours_mpi.pf"
        end do
        call mpi_env_free(env)
    end subroutine check_case

    pure integer(i8) function image_key(id, sx, sy, sz)
        integer(i8), intent(in) :: id
        integer, intent(in) :: sx, sy, sz
        image_key = id * 27_i8 + int((sx + 1) + 3 * (sy + 1) + 9 * (sz + 1), i8)
    end function image_key

    subroutine sort_i8(a)
        integer(i8), intent(inout) :: a(:)
        integer :: i, j
        integer(i8) :: t
        do i = 2, size(a)
            t = a(i)
            j = i - 1
            do while (j >= 1)
                if (a(j) <= t) exit
                a(j + 1) = a(j)
                j = j - 1
            end do
            a(j + 1) = t
        end do
    end subroutine sort_i8

    !@test(npes=[1, 2, 3, 4])
    subroutine test_2d_periodic_in_x_and_y(this)
        class(MpiTestMethod), intent(inout) :: this
        call check_case(this, 2, [.true., .true., .false.])
    end subroutine test_2d_periodic_in_x_and_y

    !@test(npes=[1, 2, 3, 4])
    subroutine test_2d_periodic_in_x_only(this)
        class(MpiTestMethod), intent(inout) :: this
        call check_case(this, 2, [.true., .false., .false.])
    end subroutine test_2d_periodic_in_x_only

    !@test(npes=[1, 2, 3, 4])
    subroutine test_3d_periodic_in_x_and_z(this)
        class(MpiTestMethod), intent(inout) :: this
        call check_case(this, 3, [.true., .false., .true.])
    end subroutine test_3d_periodic_in_x_and_z

    !@test(npes=[1, 3])
    subroutine test_3d_fully_periodic(this)
        class(MpiTestMethod), intent(inout) :: this
        call check_case(this, 3, [.true., .true., .true.])
    end subroutine test_3d_fully_periodic
end module test_sph_neighbours_mpi

module Wraptest_sph_neighbours_mpi
   use FUnit
   use test_sph_neighbours_mpi
   implicit none
   private

contains


end module Wraptest_sph_neighbours_mpi

function test_sph_neighbours_mpi_suite() result(suite)
   use FUnit
   use test_sph_neighbours_mpi
   use Wraptest_sph_neighbours_mpi
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_neighbours_mpi_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_and_y', &
      test_2d_periodic_in_x_and_y, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_and_y', &
      test_2d_periodic_in_x_and_y, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_and_y', &
      test_2d_periodic_in_x_and_y, 3))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_and_y', &
      test_2d_periodic_in_x_and_y, 4))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_only', &
      test_2d_periodic_in_x_only, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_only', &
      test_2d_periodic_in_x_only, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_only', &
      test_2d_periodic_in_x_only, 3))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_2d_periodic_in_x_only', &
      test_2d_periodic_in_x_only, 4))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_3d_periodic_in_x_and_z', &
      test_3d_periodic_in_x_and_z, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_3d_periodic_in_x_and_z', &
      test_3d_periodic_in_x_and_z, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_3d_periodic_in_x_and_z', &
      test_3d_periodic_in_x_and_z, 3))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_3d_periodic_in_x_and_z', &
      test_3d_periodic_in_x_and_z, 4))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_3d_fully_periodic', &
      test_3d_fully_periodic, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_3d_fully_periodic', &
      test_3d_fully_periodic, 3))
   call suite%addTest(t)


end function test_sph_neighbours_mpi_suite

