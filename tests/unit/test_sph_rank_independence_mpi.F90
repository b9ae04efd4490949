! Results do not depend on the number of ranks: the Poiseuille and Couette channels run for
! 1,000 steps on 1, 2, 3 and 4 ranks (sub-communicators of a 4-rank job) and give the same
! particles (count and ids) and velocities within 1e-9 of the peak velocity.
module test_sph_rank_independence_mpi
    use pfunit
    use mpi_f08, only: MPI_Comm
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_from_comm, mpi_env_split, mpi_env_free, &
        global_sum, global_max
    use sph_simulation, only: simulation_t, simulation_setup, simulation_step
    use test_sph_cases, only: config_from_text, channel_text
    implicit none

    integer, parameter :: n_steps = 1000

contains

    !> Run the case on the first n ranks; every rank of env receives the velocity of each
    !> particle by id, and its presence (count of holders).
    subroutine run_on(env, case, n, n_ids, velocity, holders)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: case
        integer, intent(in) :: n, n_ids
        real(wp), intent(out) :: velocity(3, n_ids)
        integer(i8), intent(out) :: holders(n_ids)
        type(mpi_env_t) :: sub
        type(simulation_t) :: sim
        logical :: member
        integer :: step, i
        velocity = 0.0_wp
        holders = 0
        call mpi_env_split(env, merge(0, -1, env%rank < n), sub, member)
        if (member) then
            call simulation_setup(sim, sub, config_from_text(channel_text(case, 20, 1.0_wp)))
            do step = 1, n_steps
                call simulation_step(sim, sub)
            end do
            do i = 1, sim%p%n_owned
                velocity(:, sim%p%id(i)) = sim%p%v(:, i)
                holders(sim%p%id(i)) = holders(sim%p%id(i)) + 1
            end do
            call mpi_env_free(sub)
        end if
        velocity = reshape(global_sum(env, reshape(velocity, [3 * n_ids])), [3, n_ids])
        holders = global_sum(env, holders)
    end subroutine run_on

    subroutine compare_rank_counts(this, case)
        class(MpiTestMethod), intent(inout) :: this
        character(len=*), intent(in) :: case
        type(MPI_Comm) :: comm
        type(mpi_env_t) :: env
        integer, parameter :: n_ids = 2000
        real(wp) :: v1(3, n_ids), vn(3, n_ids), peak, difference
        integer(i8) :: h1(n_ids), hn(n_ids)
        integer :: n
        comm%mpi_val = this%getMpiCommunicator()
        call mpi_env_from_comm(env, comm)
        call run_on(env, case, 1, n_ids, v1, h1)
        peak = maxval(abs(v1))
#line 61 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
  call assertGreaterThan(peak, 0.0_wp, message='the flow has started', &
 & location=SourceLocation( &
 & 'test_sph_rank_independence_mpi.pf', &
 & 61) )
  if (anyExceptions()) return
#line 62 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
#line 62 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
  call assertEqual(260_i8, sum(h1), 'particle count of the 1-rank run (200 fluid, 60 wall)', &
 & location=SourceLocation( &
 & 'test_sph_rank_independence_mpi.pf', &
 & 62) )
  if (anyExceptions()) return
#line 63 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
        do n = 2, env%nranks
            call run_on(env, case, n, n_ids, vn, hn)
#line 65 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
  call assertTrue(all(h1 == hn), 'the same particle ids, each on exactly one rank', &
 & location=SourceLocation( &
 & 'test_sph_rank_independence_mpi.pf', &
 & 65) )
  if (anyExceptions()) return
#line 66 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
            difference = maxval(abs(vn - v1))
#line 67 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
  call assertLessThan(difference, 1.0e-9_wp * peak, message='velocities agree with the 1-rank run', &
 & location=SourceLocation( &
 & 'test_sph_rank_independence_mpi.pf', &
 & 67) )
  if (anyExceptions()) return
#line 68 "/work/main/tests/unit/test_sph_rank_independence_mpi.pf"
        end do
        call mpi_env_free(env)
    end subroutine compare_rank_counts

    !@test(npes=[4])
    subroutine test_poiseuille_same_on_1_to_4_ranks(this)
        class(MpiTestMethod), intent(inout) :: this
        call compare_rank_counts(this, 'poiseuille')
    end subroutine test_poiseuille_same_on_1_to_4_ranks

    !@test(npes=[4])
    subroutine test_couette_same_on_1_to_4_ranks(this)
        class(MpiTestMethod), intent(inout) :: this
        call compare_rank_counts(this, 'couette')
    end subroutine test_couette_same_on_1_to_4_ranks
end module test_sph_rank_independence_mpi

module Wraptest_sph_rank_independence_mpi
   use FUnit
   use test_sph_rank_independence_mpi
   implicit none
   private

contains


end module Wraptest_sph_rank_independence_mpi

function test_sph_rank_independence_mpi_suite() result(suite)
   use FUnit
   use test_sph_rank_independence_mpi
   use Wraptest_sph_rank_independence_mpi
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_rank_independence_mpi_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_poiseuille_same_on_1_to_4_ranks', &
      test_poiseuille_same_on_1_to_4_ranks, 4))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=MpiTestMethod('test_couette_same_on_1_to_4_ranks', &
      test_couette_same_on_1_to_4_ranks, 4))
   call suite%addTest(t)


end function test_sph_rank_independence_mpi_suite

