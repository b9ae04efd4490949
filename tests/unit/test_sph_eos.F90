! Equations of state, Morris' sound-speed criterion and the time-step limits.
module test_sph_eos
    use funit
    use sph_kinds, only: wp
    use sph_eos, only: EOS_MORRIS, EOS_MORRIS_RELATIVE, EOS_TAIT, eos_pressure, morris_sound_speed
    use sph_timestep, only: timestep_limits_t, timestep_limits
    implicit none

contains

    !@test
    subroutine test_morris_forms()
        real(wp) :: p
        p = eos_pressure(EOS_MORRIS, 1001.0_wp, 1000.0_wp, 2.0_wp, 7.0_wp)
#line 15 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(4.0_wp * 1001.0_wp, p, 1.0e-14_wp, 'p = c^2 rho', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 15) )
  if (anyExceptions()) return
#line 16 "/work/main/tests/unit/test_sph_eos.pf"
        p = eos_pressure(EOS_MORRIS_RELATIVE, 1001.0_wp, 1000.0_wp, 2.0_wp, 7.0_wp)
#line 17 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(4.0_wp, p, 1.0e-12_wp, 'p = c^2 (rho - rho0)', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 17) )
  if (anyExceptions()) return
#line 18 "/work/main/tests/unit/test_sph_eos.pf"
        p = eos_pressure(EOS_MORRIS_RELATIVE, 1000.0_wp, 1000.0_wp, 2.0_wp, 7.0_wp)
#line 19 "/work/main/tests/unit/test_sph_eos.pf"
  call assertEqual(0.0_wp, p, 'no pressure at the rest density', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 19) )
  if (anyExceptions()) return
#line 20 "/work/main/tests/unit/test_sph_eos.pf"
    end subroutine test_morris_forms

    !@test
    subroutine test_tait_reference_and_linear_limit()
        real(wp) :: c, rho0, drho, p, slope
        c = 3.0_wp
        rho0 = 1000.0_wp
        drho = 1.0e-4_wp
        p = eos_pressure(EOS_TAIT, rho0, rho0, c, 7.0_wp)
#line 29 "/work/main/tests/unit/test_sph_eos.pf"
  call assertEqual(0.0_wp, p, 'Tait pressure vanishes at rho0', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 29) )
  if (anyExceptions()) return
#line 30 "/work/main/tests/unit/test_sph_eos.pf"
        slope = (eos_pressure(EOS_TAIT, rho0 + drho, rho0, c, 7.0_wp) &
            - eos_pressure(EOS_TAIT, rho0 - drho, rho0, c, 7.0_wp)) / (2.0_wp * drho)
#line 32 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(c * c, slope, 1.0e-6_wp, 'Tait slope dp/drho at rho0 is c^2', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 32) )
  if (anyExceptions()) return
#line 33 "/work/main/tests/unit/test_sph_eos.pf"
    end subroutine test_tait_reference_and_linear_limit

    !@test
    subroutine test_morris_sound_speed_criterion()
        real(wp) :: c, expected
        ! Morris' Poiseuille case: F L dominates, c^2 = F L / delta
        c = morris_sound_speed(2.5e-5_wp, 1.0e-6_wp, 1.0e-3_wp, 2.0e-4_wp, 0.01_wp)
        expected = sqrt(2.0e-4_wp * 1.0e-3_wp / 0.01_wp)
#line 41 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(expected, c, 1.0e-14_wp, 'force term dominates', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 41) )
  if (anyExceptions()) return
#line 42 "/work/main/tests/unit/test_sph_eos.pf"
        ! Couette at low Reynolds number: nu V / L dominates V^2
        c = morris_sound_speed(2.5e-5_wp, 1.0e-6_wp, 1.0e-3_wp, 0.0_wp, 0.01_wp)
        expected = sqrt(1.0e-6_wp * 2.5e-5_wp / 1.0e-3_wp / 0.01_wp)
#line 45 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(expected, c, 1.0e-14_wp, 'viscous term dominates', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 45) )
  if (anyExceptions()) return
#line 46 "/work/main/tests/unit/test_sph_eos.pf"
        c = morris_sound_speed(1.0_wp, 1.0e-6_wp, 1.0_wp, 0.0_wp, 0.01_wp)
#line 47 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(10.0_wp, c, 1.0e-14_wp, 'inertial term dominates at high Re', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 47) )
  if (anyExceptions()) return
#line 48 "/work/main/tests/unit/test_sph_eos.pf"
    end subroutine test_morris_sound_speed_criterion

    !@test
    subroutine test_timestep_limits()
        type(timestep_limits_t) :: lim
        lim = timestep_limits(2.0_wp, 10.0_wp, 0.0_wp, 0.5_wp, 8.0_wp, 0.25_wp, 0.125_wp, 0.25_wp)
#line 54 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(0.05_wp, lim%cfl, 1.0e-14_wp, 'CFL limit 0.25 h / c', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 54) )
  if (anyExceptions()) return
#line 55 "/work/main/tests/unit/test_sph_eos.pf"
#line 55 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(1.0_wp, lim%viscous, 1.0e-14_wp, 'viscous limit 0.125 h^2 / nu', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 55) )
  if (anyExceptions()) return
#line 56 "/work/main/tests/unit/test_sph_eos.pf"
#line 56 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(0.125_wp, lim%force, 1.0e-14_wp, 'force limit 0.25 sqrt(h / f)', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 56) )
  if (anyExceptions()) return
#line 57 "/work/main/tests/unit/test_sph_eos.pf"
#line 57 "/work/main/tests/unit/test_sph_eos.pf"
  call assertEqual(lim%cfl, lim%dt, 'dt is the smallest limit', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 57) )
  if (anyExceptions()) return
#line 58 "/work/main/tests/unit/test_sph_eos.pf"
        lim = timestep_limits(2.0_wp, 10.0_wp, 10.0_wp, 0.0_wp, 0.0_wp, 0.25_wp, 0.125_wp, 0.25_wp)
#line 59 "/work/main/tests/unit/test_sph_eos.pf"
  call assertRelativelyEqual(0.025_wp, lim%dt, 1.0e-14_wp, 'flow speed adds to c; no nu or f limit', &
 & location=SourceLocation( &
 & 'test_sph_eos.pf', &
 & 59) )
  if (anyExceptions()) return
#line 60 "/work/main/tests/unit/test_sph_eos.pf"
    end subroutine test_timestep_limits
end module test_sph_eos

module Wraptest_sph_eos
   use FUnit
   use test_sph_eos
   implicit none
   private

contains


end module Wraptest_sph_eos

function test_sph_eos_suite() result(suite)
   use FUnit
   use test_sph_eos
   use Wraptest_sph_eos
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_eos_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_morris_forms', &
      test_morris_forms))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_tait_reference_and_linear_limit', &
      test_tait_reference_and_linear_limit))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_morris_sound_speed_criterion', &
      test_morris_sound_speed_criterion))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_timestep_limits', &
      test_timestep_limits))
   call suite%addTest(t)


end function test_sph_eos_suite

