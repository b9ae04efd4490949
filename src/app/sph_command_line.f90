!> Command-line options of the sphremesh program. Parsed identically on every rank.
module sph_command_line
    implicit none
    private
    public :: options_t, parse_command_line, usage_text

    type :: options_t
        logical :: show_help = .false.
        logical :: show_version = .false.
        logical :: check_only = .false.     !< --check: set up, report, write nothing
        !> --continue: from the newest complete checkpoint of the input's case in its
        !> output_dir when that holds one, else a fresh start (a job chain's links)
        logical :: continue_run = .false.
        character(len=:), allocatable :: input_file
        character(len=:), allocatable :: restart_from   !< checkpoint file or directory, '' = none
        !> --remesh MODE IN OUT: remesh a snapshot or checkpoint offline ('' = not asked)
        character(len=:), allocatable :: remesh_mode, remesh_in, remesh_out
        !> --regions INPUT.nml with --remesh refine: refine only the &region groups of that
        !> input in the uniform state IN, OUT a multi-resolution checkpoint ('' = not asked)
        character(len=:), allocatable :: regions_input
    end type options_t

contains

    !> Parse the program's arguments into opts; stat /= 0 and errmsg on a bad command line.
    subroutine parse_command_line(opts, stat, errmsg)
        type(options_t), intent(out) :: opts
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer :: i, n
        character(len=:), allocatable :: arg

        stat = 0
        errmsg = ''
        opts%input_file = ''
        opts%restart_from = ''
        opts%remesh_mode = ''
        opts%remesh_in = ''
        opts%remesh_out = ''
        opts%regions_input = ''
        n = command_argument_count()
        i = 1
        do while (i <= n)
            arg = argument(i)
            select case (arg)
            case ('-h', '--help')
                opts%show_help = .true.
            case ('-V', '--version')
                opts%show_version = .true.
            case ('--check')
                ! (given twice, as --restart is refused: a command line built by a script
                ! that repeats itself)
                if (opts%check_only) then
                    stat = 1
                    errmsg = '--check given twice'
                    return
                end if
                opts%check_only = .true.
            case ('--continue')
                if (opts%continue_run) then
                    stat = 1
                    errmsg = '--continue given twice'
                    return
                end if
                opts%continue_run = .true.
            case ('--restart')
                call option_value(i, n, arg, 'a checkpoint file or a directory of ' // &
                    'checkpoints', opts%restart_from, stat, errmsg)
                if (stat /= 0) return
            case ('--regions')
                call option_value(i, n, arg, 'an input file with &region groups', &
                    opts%regions_input, stat, errmsg)
                if (stat /= 0) return
            case ('--remesh')
                if (i + 3 > n) then
                    stat = 1
                    errmsg = '--remesh needs a mode (refine, coarsen or same), an input ' // &
                        'snapshot or checkpoint and an output checkpoint'
                    return
                end if
                if (len(opts%remesh_mode) > 0) then
                    stat = 1
                    errmsg = '--remesh given twice'
                    return
                end if
                opts%remesh_mode = argument(i + 1)
                opts%remesh_in = argument(i + 2)
                opts%remesh_out = argument(i + 3)
                i = i + 3
                if (len_trim(opts%remesh_in) == 0 .or. len_trim(opts%remesh_out) == 0) then
                    stat = 1
                    errmsg = '--remesh: IN and OUT must be file names, not empty arguments'
                    return
                end if
                if (is_option(opts%remesh_in) .or. is_option(opts%remesh_out)) then
                    stat = 1
                    if (is_option(opts%remesh_in)) then
                        errmsg = "--remesh needs IN, got the option '" // opts%remesh_in // "'"
                    else
                        errmsg = "--remesh needs OUT, got the option '" // opts%remesh_out // &
                            "'"
                    end if
                    return
                end if
                if (all(opts%remesh_mode /= [character(len=7) :: 'refine', 'coarsen', 'same'])) &
                    then
                    stat = 1
                    errmsg = "--remesh: unknown mode '" // opts%remesh_mode // &
                        "' (refine, coarsen or same)"
                    return
                end if
            case default
                if (arg(1:1) == '-') then
                    stat = 1
                    errmsg = "unknown option '" // arg // "' (see sphremesh --help)"
                    return
                end if
                if (len(opts%input_file) > 0) then
                    stat = 1
                    errmsg = "only one input file may be given, got '" // opts%input_file // &
                        "' and '" // arg // "'"
                    return
                end if
                opts%input_file = arg
            end select
            i = i + 1
        end do
        ! each option belongs to one way of running (sphremesh --help): a combination would
        ! leave one of them silently unused
        if (len(opts%remesh_mode) > 0 .and. (opts%check_only .or. &
            len(opts%restart_from) > 0)) then
            stat = 1
            errmsg = '--remesh takes neither --check nor --restart (it writes a checkpoint; ' // &
                'continue from it with a second command, sphremesh INPUT.nml --restart OUT)'
            return
        end if
        if (len(opts%regions_input) > 0 .and. opts%remesh_mode /= 'refine') then
            stat = 1
            errmsg = '--regions goes with --remesh refine IN OUT (it refines the regions of ' // &
                'its input in the uniform state IN)'
            return
        end if
        if (opts%check_only .and. len(opts%restart_from) > 0) then
            stat = 1
            errmsg = '--check sets up a fresh run and takes no --restart'
            return
        end if
        if (opts%continue_run .and. (opts%check_only .or. len(opts%restart_from) > 0 .or. &
            len(opts%remesh_mode) > 0)) then
            stat = 1
            errmsg = '--continue takes neither --check, --restart nor --remesh (it restarts ' // &
                "from the newest checkpoint of the input's case in its output_dir, or starts " // &
                'the run when there is none)'
            return
        end if
        if (len(opts%remesh_mode) > 0 .and. len(opts%input_file) > 0) then
            stat = 1
            errmsg = "'" // opts%input_file // "' is an argument too many: --remesh takes " // &
                'MODE IN OUT and no input file (it uses the input stored in ' // &
                opts%remesh_in // ')'
            return
        end if
        if (.not. (opts%show_help .or. opts%show_version) .and. len(opts%input_file) == 0 &
            .and. len(opts%remesh_mode) == 0) then
            stat = 1
            errmsg = 'no input file given (usage: sphremesh INPUT.nml ' // &
                '[--restart CHECKPOINT | --continue]; see sphremesh --help)'
        end if
    end subroutine parse_command_line

    !> The value of option `name` (argument i, at most n) into value, i moved onto it: it
    !> must be there, not empty, and not given before ('' = not yet).
    subroutine option_value(i, n, name, what, value, stat, errmsg)
        integer, intent(inout) :: i
        integer, intent(in) :: n
        character(len=*), intent(in) :: name, what
        character(len=:), allocatable, intent(inout) :: value
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(inout) :: errmsg
        stat = 1
        if (i == n) then
            errmsg = name // ' needs ' // what
            return
        end if
        i = i + 1
        if (len(value) > 0) then
            errmsg = name // " given twice ('" // value // "' and '" // argument(i) // "')"
            return
        end if
        value = argument(i)
        if (len_trim(value) == 0) then
            errmsg = name // ' needs ' // what // ', not an empty argument'
            return
        end if
        ! (the next option taken for the value: "cannot open '--continue' as an HDF5 file")
        if (is_option(value)) then
            errmsg = name // ' needs ' // what // ", got the option '" // value // "'"
            return
        end if
        stat = 0
    end subroutine option_value

    !> Whether arg is one of the command line's options (a file name does not start so).
    pure logical function is_option(arg)
        character(len=*), intent(in) :: arg
        is_option = any(arg == [character(len=10) :: '--help', '-h', '--version', '--check', &
            '--continue', '--restart', '--regions', '--remesh'])
    end function is_option

    function argument(i) result(arg)
        integer, intent(in) :: i
        character(len=:), allocatable :: arg
        integer :: length
        call get_command_argument(i, length=length)
        allocate(character(len=length) :: arg)
        if (length > 0) call get_command_argument(i, arg)
    end function argument

    !> The usage message printed for --help and after a bad command line.
    function usage_text() result(text)
        character(len=:), allocatable :: text
        character(len=*), parameter :: nl = new_line('a')
        text = &
            'usage: mpirun -np N sphremesh INPUT.nml [--restart CHECKPOINT.h5|DIR | --continue]' &
            // nl // &
            '       mpirun -np N sphremesh --check INPUT.nml' // nl // &
            '       mpirun -np N sphremesh --remesh refine|coarsen|same IN.h5 OUT.h5' // nl // &
            '       mpirun -np N sphremesh --remesh refine IN.h5 OUT.h5 --regions INPUT.nml' // &
            nl // &
            '       sphremesh --help | --version' // nl // nl // &
            'Smoothed Particle Hydrodynamics for low-Reynolds-number, nearly incompressible' // &
            nl // 'flows, configured by a Fortran namelist file (see doc/input.md and ' // &
            'input/).' // &
            nl // nl // &
            'options:' // nl // &
            '  -h, --help         print this help and exit' // nl // &
            '  -V, --version      print the version, git hash and build options and exit' // &
            nl // &
            '  --restart PATH     continue from a checkpoint file, or from the newest' // nl // &
            '                     complete checkpoint in directory PATH' // nl // &
            '  --continue         continue from the newest complete checkpoint of the' // nl // &
            "                     input's case in its &output output_dir, or start the run" // &
            nl // &
            '                     when that holds no checkpoint file of the case (only' // &
            nl // &
            '                     damaged ones: an error); a run already at its end' // &
            nl // &
            '                     exits 0 and writes nothing; for job chains' // nl // &
            '  --check            check the input and set the run up: print the particle' // &
            nl // &
            '                     counts, memory, time step and steps, then stop (no output)' // &
            nl // &
            '  --remesh MODE IN OUT  remesh the fluid of snapshot or checkpoint IN (refine:' // &
            nl // &
            '                     dx/2, coarsen: 2 dx, same: same dx) into checkpoint OUT;' // &
            nl // &
            '                     continue with --restart OUT and &domain dx = the new dx' // &
            nl // &
            '  --regions INPUT.nml  with --remesh refine: refine only the &region groups of' // &
            nl // &
            '                     INPUT.nml in the uniform checkpoint IN; OUT is a' // nl // &
            '                     multi-resolution checkpoint: continue with' // nl // &
            '                     sphremesh INPUT.nml --restart OUT' // &
            nl // nl // &
            'namelist groups: &run &output &domain &fluid &numerics &parallel &restart' // nl // &
            '                 &health &remesh &body &refinement &region (see doc/input.md)' // &
            nl // &
            'example: mpirun -np 2 sphremesh input/poiseuille.nml'
    end function usage_text
end module sph_command_line
