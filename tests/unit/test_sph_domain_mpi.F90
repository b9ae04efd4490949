! Domain decomposition on 1 to 4 ranks: the ORB subdomains tile the box without overlap and
! agree with the owner lookup; migration keeps every particle exactly once with its id, kind
! and level; a deliberately non-uniform set is balanced below the rebalance threshold.
module test_sph_domain_mpi
    use pfunit
    use mpi_f08, only: MPI_Comm
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_from_comm, mpi_env_free, global_sum
    use sph_particles, only: particles_t, particles_init, KIND_FLUID, KIND_WALL
    use sph_domain, only: domain_t, domain_create, domain_partition, domain_owner, &
        migrate_particles, domain_imbalance, far
    use test_sph_random, only: random_points, random_uniform
    implicit none

contains

    !@test(npes=[1, 2, 3, 4])
    subroutine test_partition_tiles_box(this)
        class(MpiTestMethod), intent(inout) :: this
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(domain_t) :: domain
        real(wp), allocatable :: x(:, :)
        real(wp) :: lo(3), hi(3), volume, overlap, blo(3), bhi(3), inside
        integer :: r, s, i, hits
        logical :: periodic(3)

        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        lo = [0.0_wp, 0.0_wp, 0.0_wp]
        hi = [3.0_wp, 2.0_wp, 1.0_wp]
        periodic = [.true., .false., .true.]
        call domain_create(domain, env, 3, lo, hi, periodic)
        call random_points(400, 3, lo, hi, 77_i8 + env%rank, x)
        call domain_partition(domain, env, x, 400)
        volume = 0.0_wp
        do r = 0, env%nranks - 1
            volume = volume + box_volume(domain%box_lo(:, r), domain%box_hi(:, r))
            do s = r + 1, env%nranks - 1
                blo = max(domain%box_lo(:, r), domain%box_lo(:, s))
                bhi = min(domain%box_hi(:, r), domain%box_hi(:, s))
                overlap = box_volume(blo, bhi)
#line 43 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertEqual(0.0_wp, overlap, 'subdomains do not overlap', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 43) )
  if (anyExceptions()) return
#line 44 "/work/main/tests/unit/test_sph_domain_mpi.pf"
            end do
        end do
#line 46 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertRelativelyEqual(6.0_wp, volume, 1.0e-12_wp, 'subdomains cover the box exactly', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 46) )
  if (anyExceptions()) return
#line 47 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        ! the owner lookup agrees with the boxes, for points anywhere (walls: outside too)
        call random_points(500, 3, lo - [0.0_wp, 0.5_wp, 0.0_wp], hi + [0.0_wp, 0.5_wp, 0.0_wp], &
            999_i8, x)
        do i = 1, 500
            hits = 0
            do r = 0, env%nranks - 1
                if (all(x(:, i) >= domain%box_lo(:, r) .and. x(:, i) < domain%box_hi(:, r))) then
                    hits = hits + 1
                    inside = real(r, wp)
                end if
            end do
#line 58 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertEqual(1, hits, 'every point lies in exactly one subdomain', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 58) )
  if (anyExceptions()) return
#line 59 "/work/main/tests/unit/test_sph_domain_mpi.pf"
#line 59 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertEqual(nint(inside), domain_owner(domain, x(:, i)), 'owner lookup matches the box', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 59) )
  if (anyExceptions()) return
#line 60 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        end do
        call mpi_env_free(env)
    contains
        !> Volume of the part of a box inside the global box (open faces clipped).
        real(wp) function box_volume(a, b)
            real(wp), intent(in) :: a(3), b(3)
            real(wp) :: ca(3), cb(3)
            ca = max(a, lo)
            cb = min(b, hi)
            box_volume = product(max(cb - ca, 0.0_wp))
        end function box_volume
    end subroutine test_partition_tiles_box

    !@test(npes=[1, 2, 3, 4])
    subroutine test_migration_keeps_every_particle(this)
        class(MpiTestMethod), intent(inout) :: this
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(domain_t) :: domain
        type(particles_t) :: p
        real(wp), allocatable :: x(:, :)
        integer(i8), allocatable :: seen(:)
        integer(i8) :: state
        integer :: i, n_global, n, r
        real(wp) :: lo(3), hi(3)
        logical :: ok

        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        lo = 0.0_wp
        hi = [1.0_wp, 1.0_wp, 0.0_wp]
        n_global = 1000
        call domain_create(domain, env, 2, lo, hi, [.true., .true., .false.])
        call random_points(n_global, 2, lo, hi, 4242_i8, x)
        ! deal particles to ranks round-robin (mostly the wrong owner), some outside the box
        call particles_init(p, n_global, 2)
        state = 31_i8
        n = 0
        do i = 1, n_global
            if (mod(i, env%nranks) /= env%rank) cycle
            n = n + 1
            p%x(:, n) = x(:, i) + [merge(1.0_wp, 0.0_wp, mod(i, 7) == 0), 0.0_wp, 0.0_wp]
            p%v(:, n) = [random_uniform(state), 0.0_wp, 0.0_wp]
            p%id(n) = int(i, i8)
            p%kind(n) = merge(KIND_WALL, KIND_FLUID, mod(i, 5) == 0)
            p%level(n) = mod(i, 3)
        end do
        p%n_owned = n
        p%n_total = n
        call domain_partition(domain, env, p%x, p%n_owned)
        call migrate_particles(domain, env, p)
#line 111 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertEqual(int(n_global, i8), global_sum(env, int(p%n_owned, i8)), 'global count kept', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 111) )
  if (anyExceptions()) return
#line 112 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        allocate(seen(n_global))
        seen = 0
        ok = .true.
        do i = 1, p%n_owned
            seen(p%id(i)) = seen(p%id(i)) + 1
            r = domain_owner(domain, p%x(:, i))
            if (r /= env%rank) ok = .false.
            if (p%kind(i) /= merge(KIND_WALL, KIND_FLUID, mod(p%id(i), 5_i8) == 0)) ok = .false.
            if (p%level(i) /= mod(p%id(i), 3_i8)) ok = .false.
            if (any(p%x(1:2, i) < lo(1:2) .or. p%x(1:2, i) >= hi(1:2))) ok = .false.
        end do
#line 123 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertTrue(ok, 'each particle is on its owner, wrapped, with its kind and level', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 123) )
  if (anyExceptions()) return
#line 124 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        seen = global_sum(env, seen)
#line 125 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertTrue(all(seen == 1), 'every id is held by exactly one rank', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 125) )
  if (anyExceptions()) return
#line 126 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        call mpi_env_free(env)
    end subroutine test_migration_keeps_every_particle

    !@test(npes=[2, 3, 4])
    subroutine test_balances_nonuniform_density(this)
        class(MpiTestMethod), intent(inout) :: this
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(domain_t) :: domain
        type(particles_t) :: p
        real(wp), allocatable :: coarse(:, :), fine(:, :), fine3(:, :)
        real(wp) :: lo(3), hi(3), imbalance
        integer :: i, n

        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        ! 2D: the right quarter is 4x denser (a fine resolution level)
        lo = 0.0_wp
        hi = [4.0_wp, 1.0_wp, 0.0_wp]
        call domain_create(domain, env, 2, lo, hi, [.true., .false., .false.])
        call random_points(1500, 2, lo, [3.0_wp, 1.0_wp, 0.0_wp], 5_i8, coarse)
        call random_points(2000, 2, [3.0_wp, 0.0_wp, 0.0_wp], hi, 6_i8, fine)
        call particles_init(p, 3500, 2)
        n = 0
        if (env%rank == 0) then
            do i = 1, 1500
                n = n + 1
                p%x(:, n) = coarse(:, i)
                p%id(n) = i
            end do
            do i = 1, 2000
                n = n + 1
                p%x(:, n) = fine(:, i)
                p%id(n) = 1500 + i
            end do
        end if
        p%n_owned = n
        p%n_total = n
        call migrate_particles(domain, env, p)
        imbalance = domain_imbalance(env, p%n_owned)
#line 166 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertGreaterThan(imbalance, 1.1_wp, message='the geometric split is out of balance', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 166) )
  if (anyExceptions()) return
#line 167 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        call domain_partition(domain, env, p%x, p%n_owned)
        call migrate_particles(domain, env, p)
        imbalance = domain_imbalance(env, p%n_owned)
#line 170 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertLessThan(imbalance, 1.05_wp, message='2D: balanced below the threshold after rebalancing', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 170) )
  if (anyExceptions()) return
#line 171 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        ! 3D: an 8x denser corner
        call domain_create(domain, env, 3, [0.0_wp, 0.0_wp, 0.0_wp], [2.0_wp, 2.0_wp, 2.0_wp], &
            [.true., .true., .true.])
        call random_points(1400, 3, [0.0_wp, 0.0_wp, 0.0_wp], [2.0_wp, 2.0_wp, 2.0_wp], 7_i8, coarse)
        call random_points(1400, 3, [0.0_wp, 0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp, 1.0_wp], 8_i8, fine3)
        call particles_init(p, 2800, 3)
        n = 0
        do i = 1, 1400
            if (mod(i, env%nranks) /= env%rank) cycle
            n = n + 1
            p%x(:, n) = coarse(:, i)
            p%id(n) = i
            n = n + 1
            p%x(:, n) = fine3(:, i)
            p%id(n) = 1400 + i
        end do
        p%n_owned = n
        p%n_total = n
        call domain_partition(domain, env, p%x, p%n_owned)
        call migrate_particles(domain, env, p)
        imbalance = domain_imbalance(env, p%n_owned)
#line 192 "/work/main/tests/unit/test_sph_domain_mpi.pf"
  call assertLessThan(imbalance, 1.05_wp, message='3D: balanced below the threshold after rebalancing', &
 & location=SourceLocation( &
 & 'test_sph_domain_mpi.pf', &
 & 192) )
  if (anyExceptions()) return
#line 193 "/work/main/tests/unit/test_sph_domain_mpi.pf"
        call mpi_env_free(env)
    end subroutine test_balances_nonuniform_density
end module test_sph_domain_mpi

module Wraptest_sph_domain_mpi
   use FUnit
   use test_sph_domain_mpi
   implicit none
   private

contains


end module Wraptest_sph_domain_mpi

function test_sph_domain_mpi_suite() result(suite)
   use FUnit
   use test_sph_domain_mpi
   use Wraptest_sph_domain_mpi
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_domain_mpi_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_partition_tiles_box', &
      test_partition_tiles_box, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_partition_tiles_box', &
      test_partition_tiles_box, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_partition_tiles_box', &
      test_partition_tiles_box, 3))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_partition_tiles_box', &
      test_partition_tiles_box, 4))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_migration_keeps_every_particle', &
      test_migration_keeps_every_particle, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_migration_keeps_every_particle', &
      test_migration_keeps_every_particle, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_migration_keeps_every_particle', &
      test_migration_keeps_every_particle, 3))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_migration_keeps_every_particle', &
      test_migration_keeps_every_particle, 4))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_balances_nonuniform_density', &
      test_balances_nonuniform_density, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_balances_nonuniform_density', &
      test_balances_nonuniform_density, 3))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_balances_nonuniform_density', &
      test_balances_nonuniform_density, 4))
   call suite%addTest(t)


end function test_sph_domain_mpi_suite

