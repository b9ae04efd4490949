! Whole-solver checks on 1 to 4 ranks: a fluid at rest stays at rest, linear momentum is
! conserved to round-off, the Poiseuille start-up matches the analytic solution (regression,
! stated tolerance), and a run in which some ranks own no fluid at all goes on.
module test_sph_flow_mpi
    use pfunit
    use mpi_f08, only: MPI_Comm
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_from_comm, mpi_env_free, global_sum, global_max
    use sph_particles, only: KIND_FLUID
    use sph_simulation, only: simulation_t, simulation_setup, simulation_step, &
        simulation_analytic_error, simulation_prepare_neighbours
    use sph_domain, only: domain_partition, migrate_particles
    use sph_halo, only: halo_setup
    use sph_rates, only: local_max_speed
    use test_sph_cases, only: config_from_text, channel_text, periodic_box_text
    use test_sph_random, only: random_uniform
    implicit none

contains

    subroutine rest_case(this, dim)
        class(MpiTestMethod), intent(inout) :: this
        integer, intent(in) :: dim
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(simulation_t) :: sim
        integer :: step
        real(wp) :: vmax
        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        ! p = c^2 rho: a large background pressure whose forces cancel only by symmetry
        call simulation_setup(sim, env, config_from_text(periodic_box_text(dim, 12, 'morris')))
        do step = 1, 100
            call simulation_step(sim, env)
        end do
        vmax = global_max(env, local_max_speed(sim%p))
#line 37 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertLessThan(vmax, 1.0e-12_wp * sim%phys%c, message='fluid at rest stays at rest', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 37) )
  if (anyExceptions()) return
#line 38 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        call mpi_env_free(env)
    end subroutine rest_case

    !@test(npes=[1, 2, 3])
    subroutine test_rest_state_2d(this)
        class(MpiTestMethod), intent(inout) :: this
        call rest_case(this, 2)
    end subroutine test_rest_state_2d

    !@test(npes=[1, 2])
    subroutine test_rest_state_3d(this)
        class(MpiTestMethod), intent(inout) :: this
        call rest_case(this, 3)
    end subroutine test_rest_state_3d

    !@test(npes=[1, 2, 3])
    subroutine test_momentum_conserved(this)
        class(MpiTestMethod), intent(inout) :: this
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(simulation_t) :: sim
        integer :: i, step
        integer(i8) :: state
        real(wp) :: before(3), after(3), scale, drift
        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        call simulation_setup(sim, env, config_from_text(periodic_box_text(2, 16)))
        ! random velocities, chosen by id so that they do not depend on the rank count
        do i = 1, sim%p%n_owned
            state = 7919_i8 * sim%p%id(i) + 17_i8
            sim%p%v(1, i) = 1.0e-4_wp * (random_uniform(state) - 0.5_wp)
            sim%p%v(2, i) = 1.0e-4_wp * (random_uniform(state) - 0.5_wp)
        end do
        call simulation_prepare_neighbours(sim, env)
        before = total_momentum()
        scale = global_sum(env, sum(sim%p%m(1:sim%p%n_owned) * &
            norm2(sim%p%v(:, 1:sim%p%n_owned), dim=1)))
        do step = 1, 50
            call simulation_step(sim, env)
        end do
        after = total_momentum()
        drift = norm2(after - before) / scale
#line 80 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertLessThan(drift, 1.0e-13_wp, message='total momentum conserved to round-off', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 80) )
  if (anyExceptions()) return
#line 81 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        call mpi_env_free(env)
    contains
        function total_momentum() result(mom)
            real(wp) :: mom(3)
            integer :: k
            mom = 0.0_wp
            do k = 1, sim%p%n_owned
                mom = mom + sim%p%m(k) * sim%p%v(:, k)
            end do
            mom = global_sum(env, mom)
        end function total_momentum
    end subroutine test_momentum_conserved

    !> Regression: Morris' Poiseuille case at dx = L/40 up to t = 0.0225 s. Measured 0.22 %
    !> relative L2 error; tolerance 0.5 %.
    !@test(npes=[1, 2])
    subroutine test_poiseuille_startup_regression(this)
        class(MpiTestMethod), intent(inout) :: this
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(simulation_t) :: sim
        real(wp) :: error
        real(wp), parameter :: t_check = 0.0225_wp
        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        call simulation_setup(sim, env, config_from_text(channel_text('poiseuille', 40, t_check)))
        do while (sim%time < t_check * (1.0_wp - 1.0e-12_wp))
            call simulation_step(sim, env, t_check - sim%time)
        end do
#line 110 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertEqual(t_check, sim%time, 1.0e-15_wp, 'the step is shortened to land on the time', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 110) )
  if (anyExceptions()) return
#line 111 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        error = simulation_analytic_error(sim, env)
#line 112 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertLessThan(error, 0.005_wp, message='relative L2 velocity error below 0.5 % at t = 0.0225 s', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 112) )
  if (anyExceptions()) return
#line 113 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        call mpi_env_free(env)
    end subroutine test_poiseuille_startup_regression

    !> All cuts forced into a sliver at the lower wall: some ranks own walls only or nothing.
    !@test(npes=[4])
    subroutine test_ranks_without_fluid(this)
        class(MpiTestMethod), intent(inout) :: this
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        type(simulation_t) :: sim
        real(wp) :: sliver(3, 40), error
        integer(i8) :: n_before, n_after
        integer :: i, step, n_fake, ranks_without_fluid
        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        call simulation_setup(sim, env, config_from_text(channel_text('poiseuille', 20, 1.0_wp) // &
            '&parallel rebalance_threshold = 1000.0 /'))
        n_before = global_sum(env, int(sim%p%n_owned, i8))
        do i = 1, 40
            sliver(:, i) = [1.0e-6_wp * i, 1.0e-7_wp * i, 0.0_wp]
        end do
        n_fake = merge(40, 0, env%rank == 0)
        call domain_partition(sim%domain, env, sliver, n_fake)
        call halo_setup(sim%halo, sim%domain, sim%halo%reach)
        call migrate_particles(sim%domain, env, sim%p)
        call simulation_prepare_neighbours(sim, env)
        ranks_without_fluid = int(global_sum(env, merge(1_i8, 0_i8, &
            count(sim%p%kind(1:sim%p%n_owned) == KIND_FLUID) == 0)))
#line 141 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertGreaterThanOrEqual(ranks_without_fluid, 1, message='at least one rank owns no fluid', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 141) )
  if (anyExceptions()) return
#line 142 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        do step = 1, 40
            call simulation_step(sim, env)
        end do
        n_after = global_sum(env, int(sim%p%n_owned, i8))
#line 146 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertEqual(n_before, n_after, 'global particle count unchanged', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 146) )
  if (anyExceptions()) return
#line 147 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        error = simulation_analytic_error(sim, env)
#line 148 "/work/main/tests/unit/test_sph_flow_mpi.pf"
  call assertLessThan(error, 0.02_wp, message='the flow is still right', &
 & location=SourceLocation( &
 & 'test_sph_flow_mpi.pf', &
 & 148) )
  if (anyExceptions()) return
#line 149 "/work/main/tests/unit/test_sph_flow_mpi.pf"
        call mpi_env_free(env)
    end subroutine test_ranks_without_fluid
end module test_sph_flow_mpi

module Wraptest_sph_flow_mpi
   use FUnit
   use test_sph_flow_mpi
   implicit none
   private

contains


end module Wraptest_sph_flow_mpi

function test_sph_flow_mpi_suite() result(suite)
   use FUnit
   use test_sph_flow_mpi
   use Wraptest_sph_flow_mpi
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_flow_mpi_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_rest_state_2d', &
      test_rest_state_2d, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_rest_state_2d', &
      test_rest_state_2d, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_rest_state_2d', &
      test_rest_state_2d, 3))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_rest_state_3d', &
      test_rest_state_3d, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_rest_state_3d', &
      test_rest_state_3d, 2))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_momentum_conserved', &
      test_momentum_conserved, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_momentum_conserved', &
      test_momentum_conserved, 2))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_momentum_conserved', &
      test_momentum_conserved, 3))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_poiseuille_startup_regression', &
      test_poiseuille_startup_regression, 1))
   call suite%addTest(t)
   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_poiseuille_startup_regression', &
      test_poiseuille_startup_regression, 2))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_ranks_without_fluid', &
      test_ranks_without_fluid, 4))
   call suite%addTest(t)


end function test_sph_flow_mpi_suite

