! Input parsing and validation: defaults, clear messages naming file, group and key, all
! problems collected at once, and the resolved text reading back to the same configuration.
module test_sph_config
    use funit
    use sph_kinds, only: wp
    use sph_config, only: config_t, config_parse, config_validate, config_to_text
    implicit none

    character(len=*), parameter :: nl = new_line('a')

contains

    !@test
    subroutine test_defaults_when_groups_absent()
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, '&run t_end = 0.5 /' // nl, 'x.nml', stat, msg)
#line 19 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0, stat, 'a file with one group parses', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 19) )
  if (anyExceptions()) return
#line 20 "/work/main/tests/unit/test_sph_config.pf"
#line 20 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0.5_wp, cfg%t_end, 'given key is read', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 20) )
  if (anyExceptions()) return
#line 21 "/work/main/tests/unit/test_sph_config.pf"
#line 21 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(2, cfg%dimension, 'absent group keeps its defaults', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 21) )
  if (anyExceptions()) return
#line 22 "/work/main/tests/unit/test_sph_config.pf"
#line 22 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual('morris_relative', trim(cfg%eos), 'default equation of state', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 22) )
  if (anyExceptions()) return
#line 23 "/work/main/tests/unit/test_sph_config.pf"
    end subroutine test_defaults_when_groups_absent

    !@test
    subroutine test_unknown_key_names_file_group_and_key()
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, '&fluid viscosty = 1.0 /' // nl, 'case.nml', stat, msg)
#line 31 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(stat /= 0, 'unknown key is refused', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 31) )
  if (anyExceptions()) return
#line 32 "/work/main/tests/unit/test_sph_config.pf"
#line 32 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, 'case.nml') > 0, 'message names the file', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 32) )
  if (anyExceptions()) return
#line 33 "/work/main/tests/unit/test_sph_config.pf"
#line 33 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, '&fluid') > 0, 'message names the group', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 33) )
  if (anyExceptions()) return
#line 34 "/work/main/tests/unit/test_sph_config.pf"
#line 34 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, 'viscosty') > 0, 'message names the key', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 34) )
  if (anyExceptions()) return
#line 35 "/work/main/tests/unit/test_sph_config.pf"
#line 35 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, 'nu') > 0, 'message lists the allowed keys', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 35) )
  if (anyExceptions()) return
#line 36 "/work/main/tests/unit/test_sph_config.pf"
    end subroutine test_unknown_key_names_file_group_and_key

    !@test
    subroutine test_unknown_and_repeated_groups()
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, '&fluids nu = 1.0 /' // nl, 'case.nml', stat, msg)
#line 44 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(stat /= 0, 'misspelt group is refused, not skipped', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 44) )
  if (anyExceptions()) return
#line 45 "/work/main/tests/unit/test_sph_config.pf"
#line 45 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, '&fluids') > 0, 'message names the unknown group', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 45) )
  if (anyExceptions()) return
#line 46 "/work/main/tests/unit/test_sph_config.pf"
        call config_parse(cfg, '&run t_end=1 /' // nl // '&run t_end=2 /' // nl, 'c.nml', stat, msg)
#line 47 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(stat /= 0, 'a group given twice is refused', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 47) )
  if (anyExceptions()) return
#line 48 "/work/main/tests/unit/test_sph_config.pf"
        call config_parse(cfg, "&run case_name='a&b' /" // nl, 'c.nml', stat, msg)
#line 49 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0, stat, 'an ampersand inside a string is not a group', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 49) )
  if (anyExceptions()) return
#line 50 "/work/main/tests/unit/test_sph_config.pf"
    end subroutine test_unknown_and_repeated_groups

    !@test
    subroutine test_validation_collects_every_problem()
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, "&fluid nu = -1.0, eos = 'ideal' /" // nl // &
            '&domain dimension = 4 /' // nl, 'bad.nml', stat, msg)
#line 59 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0, stat, 'syntactically valid', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 59) )
  if (anyExceptions()) return
#line 60 "/work/main/tests/unit/test_sph_config.pf"
        call config_validate(cfg, stat, msg)
#line 61 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(3, stat, 'three invalid keys counted', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 61) )
  if (anyExceptions()) return
#line 62 "/work/main/tests/unit/test_sph_config.pf"
#line 62 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, '&fluid nu') > 0, 'nu named', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 62) )
  if (anyExceptions()) return
#line 63 "/work/main/tests/unit/test_sph_config.pf"
#line 63 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, '&fluid eos') > 0, 'eos named', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 63) )
  if (anyExceptions()) return
#line 64 "/work/main/tests/unit/test_sph_config.pf"
#line 64 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, "'morris'") > 0, 'allowed values listed', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 64) )
  if (anyExceptions()) return
#line 65 "/work/main/tests/unit/test_sph_config.pf"
#line 65 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, '&domain dimension') > 0, 'dimension named', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 65) )
  if (anyExceptions()) return
#line 66 "/work/main/tests/unit/test_sph_config.pf"
    end subroutine test_validation_collects_every_problem

    !@test
    subroutine test_box_must_hold_whole_lattice()
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, '&domain box_hi = 1.0, 1.0, dx = 0.3 /' // nl, 'b.nml', stat, msg)
        call config_validate(cfg, stat, msg)
#line 75 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(stat > 0, 'dx that does not divide the box is refused', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 75) )
  if (anyExceptions()) return
#line 76 "/work/main/tests/unit/test_sph_config.pf"
#line 76 "/work/main/tests/unit/test_sph_config.pf"
  call assertTrue(index(msg, '&domain dx') > 0, 'dx named', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 76) )
  if (anyExceptions()) return
#line 77 "/work/main/tests/unit/test_sph_config.pf"
    end subroutine test_box_must_hold_whole_lattice

    !@test
    subroutine test_resolved_text_reads_back_identically()
        type(config_t) :: cfg, again
        integer :: stat
        character(len=:), allocatable :: msg, text
        call config_parse(cfg, "&run case_name='chan', t_end=0.25 /" // nl // &
            "&domain boundary='periodic','periodic','wall','wall', wall_velocity(1,4)=3.0e-5 /" // nl // &
            '&output output_times = 0.1, 0.2 /' // nl, 'r.nml', stat, msg)
#line 87 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0, stat, 'parses', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 87) )
  if (anyExceptions()) return
#line 88 "/work/main/tests/unit/test_sph_config.pf"
        call config_validate(cfg, stat, msg)
#line 89 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0, stat, 'valid', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 89) )
  if (anyExceptions()) return
#line 90 "/work/main/tests/unit/test_sph_config.pf"
        text = config_to_text(cfg)
        call config_parse(again, text, 'resolved', stat, msg)
#line 92 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(0, stat, 'the resolved text is itself valid input', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 92) )
  if (anyExceptions()) return
#line 93 "/work/main/tests/unit/test_sph_config.pf"
        call config_validate(again, stat, msg)
#line 94 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual('chan', trim(again%case_name), 'case name survives', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 94) )
  if (anyExceptions()) return
#line 95 "/work/main/tests/unit/test_sph_config.pf"
#line 95 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(cfg%t_end, again%t_end, 'reals survive exactly', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 95) )
  if (anyExceptions()) return
#line 96 "/work/main/tests/unit/test_sph_config.pf"
#line 96 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(cfg%wall_velocity, again%wall_velocity, 'arrays survive', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 96) )
  if (anyExceptions()) return
#line 97 "/work/main/tests/unit/test_sph_config.pf"
#line 97 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(2, again%n_output_times, 'output times survive', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 97) )
  if (anyExceptions()) return
#line 98 "/work/main/tests/unit/test_sph_config.pf"
#line 98 "/work/main/tests/unit/test_sph_config.pf"
  call assertEqual(cfg%output_times(2), again%output_times(2), 'output time value survives', &
 & location=SourceLocation( &
 & 'test_sph_config.pf', &
 & 98) )
  if (anyExceptions()) return
#line 99 "/work/main/tests/unit/test_sph_config.pf"
    end subroutine test_resolved_text_reads_back_identically
end module test_sph_config

module Wraptest_sph_config
   use FUnit
   use test_sph_config
   implicit none
   private

contains


end module Wraptest_sph_config

function test_sph_config_suite() result(suite)
   use FUnit
   use test_sph_config
   use Wraptest_sph_config
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_config_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_defaults_when_groups_absent', &
      test_defaults_when_groups_absent))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_unknown_key_names_file_group_and_key', &
      test_unknown_key_names_file_group_and_key))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_unknown_and_repeated_groups', &
      test_unknown_and_repeated_groups))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_validation_collects_every_problem', &
      test_validation_collects_every_problem))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_box_must_hold_whole_lattice', &
      test_box_must_hold_whole_lattice))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_resolved_text_reads_back_identically', &
      test_resolved_text_reads_back_identically))
   call suite%addTest(t)


end function test_sph_config_suite

