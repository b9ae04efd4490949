!> Run-time configuration: namelist groups, defaults, validation and the resolved text.
!>
!> Rank 0 reads the file; its text is broadcast and every rank parses the same text, so every
!> rank reaches the same verdict and a bad input stops collectively with one message.
!> Namelist objects must be plain variables, so the group variables below are module scratch
!> used only inside config_parse/config_to_text; the result lives in config_t.
module sph_config
    use, intrinsic :: iso_fortran_env, only: iostat_end
    use sph_kinds, only: wp
    implicit none
    private
    public :: config_t, config_parse, config_validate, config_to_text, config_read_file
    public :: n_faces, face_names, axis_is_periodic, max_output_times
    public :: known_groups

    integer, parameter :: n_faces = 6
    character(len=*), parameter :: name_chars = &
        'abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_'
    integer, parameter :: max_output_times = 256
    integer, parameter :: name_len = 32, path_len = 512
    character(len=4), parameter :: face_names(n_faces) = &
        ['xlo ', 'xhi ', 'ylo ', 'yhi ', 'zlo ', 'zhi ']
    character(len=9), parameter :: known_groups(7) = &
        ['run      ', 'output   ', 'domain   ', 'fluid    ', 'numerics ', 'parallel ', 'restart  ']

    !> The resolved run configuration (defaults filled in, validated).
    type :: config_t
        ! &run
        character(len=name_len) :: case_name = 'sphremesh'
        real(wp) :: t_end = 1.0_wp
        integer :: max_steps = 100000000
        integer :: log_interval = 0            !< steps between log lines; 0 = automatic
        character(len=name_len) :: analytic = 'none'
        ! &output
        character(len=path_len) :: output_dir = 'output'
        real(wp) :: output_interval = 0.0_wp   !< 0 = first and last state only
        real(wp) :: output_times(max_output_times) = -1.0_wp
        integer :: n_output_times = 0
        ! &domain
        integer :: dimension = 2
        real(wp) :: box_lo(3) = 0.0_wp
        real(wp) :: box_hi(3) = 1.0_wp
        character(len=name_len) :: boundary(n_faces) = 'periodic'
        real(wp) :: wall_velocity(3, n_faces) = 0.0_wp
        real(wp) :: dx = 0.05_wp
        ! &fluid
        real(wp) :: rho0 = 1000.0_wp
        real(wp) :: nu = 1.0e-6_wp
        real(wp) :: body_force(3) = 0.0_wp
        character(len=name_len) :: eos = 'morris_relative'
        real(wp) :: sound_speed = 0.0_wp       !< 0 = Morris' criterion
        real(wp) :: tait_gamma = 7.0_wp
        real(wp) :: density_variation = 0.01_wp
        real(wp) :: velocity_scale = 0.0_wp    !< 0 = estimated from walls and body force
        real(wp) :: length_scale = 0.0_wp      !< 0 = smallest wall-to-wall distance or box size
        ! &numerics
        character(len=name_len) :: kernel = 'cubic'
        real(wp) :: h_factor = 0.0_wp          !< h = h_factor * dx; 0 = kernel's default
        character(len=name_len) :: density_method = 'continuity'
        character(len=name_len) :: viscosity_model = 'morris'
        character(len=name_len) :: viscosity_normalisation = 'lattice'
        character(len=name_len) :: wall_model = 'morris'
        real(wp) :: cfl = 0.25_wp
        real(wp) :: viscous_safety = 0.125_wp
        real(wp) :: force_safety = 0.25_wp
        real(wp) :: beta_max = 10.0_wp
        real(wp) :: repulsive_strength = 0.0_wp  !< D of eq. 2.18; 0 = velocity_scale**2
        real(wp) :: repulsive_r0 = 0.0_wp        !< r0 of eq. 2.18; 0 = dx/2
        integer :: repulsive_n1 = 12
        integer :: repulsive_n2 = 4
        ! &parallel
        real(wp) :: rebalance_threshold = 1.1_wp
        integer :: rebalance_check_interval = 50
        ! &restart
        integer :: checkpoint_interval_steps = 0
        real(wp) :: checkpoint_interval_wall = 0.0_wp
        integer :: checkpoints_kept = 2
        ! derived
        character(len=:), allocatable :: source_file
    contains
        procedure :: is_wall
    end type config_t

    ! ---- namelist scratch (see module comment) ----
    character(len=name_len) :: case_name, analytic, eos, kernel, density_method
    character(len=name_len) :: viscosity_model, viscosity_normalisation, wall_model
    character(len=name_len) :: boundary(n_faces)
    character(len=path_len) :: output_dir
    real(wp) :: t_end, output_interval, output_times(max_output_times)
    real(wp) :: box_lo(3), box_hi(3), wall_velocity(3, n_faces), dx
    real(wp) :: rho0, nu, body_force(3), sound_speed, tait_gamma, density_variation
    real(wp) :: velocity_scale, length_scale, h_factor, cfl, viscous_safety, force_safety
    real(wp) :: beta_max, repulsive_strength, repulsive_r0, rebalance_threshold
    real(wp) :: checkpoint_interval_wall
    integer :: max_steps, log_interval, dimension, repulsive_n1, repulsive_n2
    integer :: rebalance_check_interval, checkpoint_interval_steps, checkpoints_kept

    namelist /run/ case_name, t_end, max_steps, log_interval, analytic
    namelist /output/ output_dir, output_interval, output_times
    namelist /domain/ dimension, box_lo, box_hi, boundary, wall_velocity, dx
    namelist /fluid/ rho0, nu, body_force, eos, sound_speed, tait_gamma, density_variation, &
        velocity_scale, length_scale
    namelist /numerics/ kernel, h_factor, density_method, viscosity_model, &
        viscosity_normalisation, wall_model, cfl, &
        viscous_safety, force_safety, beta_max, repulsive_strength, repulsive_r0, &
        repulsive_n1, repulsive_n2
    namelist /parallel/ rebalance_threshold, rebalance_check_interval
    namelist /restart/ checkpoint_interval_steps, checkpoint_interval_wall, checkpoints_kept

contains

    logical pure function is_wall(self, face)
        class(config_t), intent(in) :: self
        integer, intent(in) :: face
        is_wall = trim(self%boundary(face)) == 'wall'
    end function is_wall

    logical pure function axis_is_periodic(cfg, axis)
        type(config_t), intent(in) :: cfg
        integer, intent(in) :: axis
        axis_is_periodic = trim(cfg%boundary(2*axis - 1)) == 'periodic'
    end function axis_is_periodic

    !> Read a whole file into one string (lines separated by new_line). Serial; rank 0 calls it.
    subroutine config_read_file(filename, text, stat, errmsg)
        character(len=*), intent(in) :: filename
        character(len=:), allocatable, intent(out) :: text
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer :: unit, file_size
        character(len=256) :: iomsg

        errmsg = ''
        open(newunit=unit, file=filename, status='old', action='read', access='stream', &
             form='unformatted', iostat=stat, iomsg=iomsg)
        if (stat /= 0) then
            errmsg = "cannot open input file '" // trim(filename) // "': " // trim(iomsg)
            return
        end if
        inquire(unit=unit, size=file_size)
        allocate(character(len=max(file_size, 0)) :: text)
        if (file_size > 0) read(unit, iostat=stat, iomsg=iomsg) text
        close(unit)
        if (stat /= 0) errmsg = "cannot read input file '" // trim(filename) // "': " // trim(iomsg)
    end subroutine config_read_file

    !> Parse namelist text into cfg. On error stat /= 0 and errmsg names the file, group and key.
    subroutine config_parse(cfg, text, source_name, stat, errmsg)
        type(config_t), intent(out) :: cfg
        character(len=*), intent(in) :: text, source_name
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        character(len=:), allocatable :: lines(:)
        integer :: g

        errmsg = ''
        cfg%source_file = source_name
        call split_lines(text, lines)
        call check_group_names(lines, source_name, stat, errmsg)
        if (stat /= 0) return
        call config_to_scratch(cfg)
        do g = 1, size(known_groups)
            call read_group(lines, trim(known_groups(g)), source_name, stat, errmsg)
            if (stat /= 0) return
        end do
        call scratch_to_config(cfg)
    end subroutine config_parse

    subroutine read_group(lines, group, source_name, stat, errmsg)
        character(len=*), intent(in) :: lines(:), group, source_name
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(inout) :: errmsg
        character(len=512) :: iomsg

        iomsg = ''
        select case (group)
        case ('run');      read(lines, nml=run, iostat=stat, iomsg=iomsg)
        case ('output');   read(lines, nml=output, iostat=stat, iomsg=iomsg)
        case ('domain');   read(lines, nml=domain, iostat=stat, iomsg=iomsg)
        case ('fluid');    read(lines, nml=fluid, iostat=stat, iomsg=iomsg)
        case ('numerics'); read(lines, nml=numerics, iostat=stat, iomsg=iomsg)
        case ('parallel'); read(lines, nml=parallel, iostat=stat, iomsg=iomsg)
        case ('restart');  read(lines, nml=restart, iostat=stat, iomsg=iomsg)
        end select
        if (stat == iostat_end) then   ! an absent group keeps its defaults
            stat = 0
        else if (stat /= 0) then
            errmsg = trim(source_name) // ': namelist group &' // group // ': ' // &
                trim(clean_iomsg(iomsg)) // '. Allowed keys in &' // group // ': ' // &
                group_keys(group)
        end if
    end subroutine read_group

    !> gfortran's namelist messages carry a leading "Cannot match namelist object name x";
    !> keep the message, drop any internal-unit noise.
    function clean_iomsg(iomsg) result(msg)
        character(len=*), intent(in) :: iomsg
        character(len=:), allocatable :: msg
        msg = trim(adjustl(iomsg))
        if (len(msg) == 0) msg = 'unreadable value'
    end function clean_iomsg

    function group_keys(group) result(keys)
        character(len=*), intent(in) :: group
        character(len=:), allocatable :: keys
        select case (group)
        case ('run'); keys = 'case_name, t_end, max_steps, log_interval, analytic'
        case ('output'); keys = 'output_dir, output_interval, output_times'
        case ('domain'); keys = 'dimension, box_lo, box_hi, boundary, wall_velocity, dx'
        case ('fluid'); keys = 'rho0, nu, body_force, eos, sound_speed, tait_gamma, ' // &
            'density_variation, velocity_scale, length_scale'
        case ('numerics'); keys = 'kernel, h_factor, density_method, viscosity_model, ' // &
            'viscosity_normalisation, wall_model, cfl, viscous_safety, force_safety, ' // &
            'beta_max, repulsive_strength, ' // &
            'repulsive_r0, repulsive_n1, repulsive_n2'
        case ('parallel'); keys = 'rebalance_threshold, rebalance_check_interval'
        case ('restart'); keys = 'checkpoint_interval_steps, checkpoint_interval_wall, ' // &
            'checkpoints_kept'
        case default; keys = ''
        end select
    end function group_keys

    !> Split text at new lines into a character array (one record per line, for internal reads).
    subroutine split_lines(text, lines)
        character(len=*), intent(in) :: text
        character(len=:), allocatable, intent(out) :: lines(:)
        integer :: i, n, start, longest, k
        n = 1
        longest = 0
        start = 1
        do i = 1, len(text)
            if (text(i:i) == new_line('a')) then
                n = n + 1
                longest = max(longest, i - start)
                start = i + 1
            end if
        end do
        longest = max(longest, len(text) - start + 1, 1)
        allocate(character(len=longest) :: lines(n))
        lines = ''
        k = 1
        start = 1
        do i = 1, len(text)
            if (text(i:i) == new_line('a')) then
                lines(k) = text(start:i - 1)
                k = k + 1
                start = i + 1
            end if
        end do
        if (start <= len(text)) lines(k) = text(start:)
        ! carriage returns from files edited on Windows would corrupt the last value on a line
        do k = 1, n
            do i = 1, len(lines(k))
                if (lines(k)(i:i) == achar(13)) lines(k)(i:i) = ' '
            end do
        end do
    end subroutine split_lines

    !> A misspelt group name would be skipped silently by a namelist read: refuse it, and a
    !> group given twice (the second would be ignored).
    subroutine check_group_names(lines, source_name, stat, errmsg)
        character(len=*), intent(in) :: lines(:), source_name
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(inout) :: errmsg
        integer :: k, i, j, g, seen(size(known_groups))
        character(len=1) :: quote
        character(len=:), allocatable :: name, allowed
        logical :: found

        stat = 0
        seen = 0
        do k = 1, size(lines)
            quote = ' '
            i = 1
            do while (i <= len(lines(k)))
                associate (ch => lines(k)(i:i))
                    if (quote /= ' ') then
                        if (ch == quote) quote = ' '
                    else if (ch == '"' .or. ch == "'") then
                        quote = ch
                    else if (ch == '!') then
                        exit
                    else if (ch == '&') then
                        j = i + 1
                        do while (j <= len(lines(k)))
                            if (verify(lines(k)(j:j), name_chars) /= 0) exit
                            j = j + 1
                        end do
                        name = to_lower(lines(k)(i + 1:j - 1))
                        if (len(name) > 0 .and. name /= 'end') then
                            found = .false.
                            do g = 1, size(known_groups)
                                if (name == trim(known_groups(g))) then
                                    found = .true.
                                    seen(g) = seen(g) + 1
                                    if (seen(g) > 1) then
                                        stat = 1
                                        errmsg = trim(source_name) // ': namelist group &' // &
                                            name // ' appears more than once; give each group once'
                                        return
                                    end if
                                end if
                            end do
                            if (.not. found) then
                                allowed = '&' // trim(known_groups(1))
                                do g = 2, size(known_groups)
                                    allowed = allowed // ', &' // trim(known_groups(g))
                                end do
                                stat = 1
                                errmsg = trim(source_name) // ': unknown namelist group &' // &
                                    name // '. Allowed groups: ' // allowed
                                return
                            end if
                        end if
                        i = j - 1
                    end if
                end associate
                i = i + 1
            end do
        end do
    end subroutine check_group_names

    pure function to_lower(s) result(r)
        character(len=*), intent(in) :: s
        character(len=len(s)) :: r
        integer :: i, c
        r = s
        do i = 1, len(s)
            c = iachar(s(i:i))
            if (c >= iachar('A') .and. c <= iachar('Z')) r(i:i) = achar(c + 32)
        end do
    end function to_lower

    !> Validate every key, collect all problems, and report them together.
    subroutine config_validate(cfg, stat, errmsg)
        type(config_t), intent(inout) :: cfg
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer :: axis, f, k, n
        real(wp) :: length, cells

        errmsg = ''
        stat = 0
        call lower_names(cfg)
        if (len_trim(cfg%case_name) == 0 .or. verify(trim(cfg%case_name), &
            'abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-.') /= 0) &
            call add('&run case_name', &
                'letters, digits, "_", "-" and "." only (used in file names)')
        if (.not. (cfg%t_end > 0.0_wp)) call add('&run t_end', 'must be > 0 (s)')
        if (cfg%max_steps < 1) call add('&run max_steps', 'must be >= 1')
        if (cfg%log_interval < 0) call add('&run log_interval', 'must be >= 0 (0 = automatic)')
        call check_choice('&run analytic', cfg%analytic, [character(len=12) :: 'none', &
            'poiseuille', 'couette'])
        if (len_trim(cfg%output_dir) == 0) call add('&output output_dir', 'must not be empty')
        if (cfg%output_interval < 0.0_wp) call add('&output output_interval', &
            'must be >= 0 (s; 0 = first and last state only)')
        n = 0
        do k = 1, max_output_times
            if (cfg%output_times(k) >= 0.0_wp) n = k
        end do
        cfg%n_output_times = n
        do k = 1, n
            if (cfg%output_times(k) < 0.0_wp .or. cfg%output_times(k) > cfg%t_end) then
                call add('&output output_times', 'every entry must lie in [0, t_end] and be ' // &
                    'given without gaps')
                exit
            end if
            if (k > 1) then
                if (cfg%output_times(k) <= cfg%output_times(k - 1)) then
                    call add('&output output_times', 'must be strictly increasing')
                    exit
                end if
            end if
        end do
        if (cfg%dimension /= 2 .and. cfg%dimension /= 3) &
            call add('&domain dimension', 'must be 2 or 3')
        if (.not. (cfg%dx > 0.0_wp)) call add('&domain dx', 'must be > 0 (m)')
        do f = 1, n_faces
            call check_choice('&domain boundary(' // trim(face_names(f)) // ')', &
                cfg%boundary(f), [character(len=12) :: 'periodic', 'wall'])
        end do
        do axis = 1, min(max(cfg%dimension, 2), 3)
            length = cfg%box_hi(axis) - cfg%box_lo(axis)
            if (.not. (length > 0.0_wp)) then
                call add('&domain box_hi(' // achar(iachar('0') + axis) // ')', &
                    'must exceed box_lo on every axis in use')
                cycle
            end if
            if ((cfg%boundary(2*axis - 1) == 'periodic') .neqv. &
                (cfg%boundary(2*axis) == 'periodic')) &
                call add('&domain boundary(' // trim(face_names(2*axis - 1)) // ', ' // &
                    trim(face_names(2*axis)) // ')', &
                        'both faces of an axis are periodic or neither is')
            if (cfg%dx > 0.0_wp) then
                cells = length / cfg%dx
                if (abs(cells - nint(cells)) > 1.0e-6_wp * cells .or. nint(cells) < 1) &
                    call add('&domain dx', 'box length on axis ' // achar(iachar('0') + axis) // &
                        ' must be a whole multiple of dx (the lattice must close periodically ' // &
                        'and sit symmetrically between walls)')
            end if
        end do
        if (.not. (cfg%rho0 > 0.0_wp)) call add('&fluid rho0', 'must be > 0 (kg/m^3)')
        if (cfg%nu < 0.0_wp) call add('&fluid nu', 'must be >= 0 (m^2/s)')
        call check_choice('&fluid eos', cfg%eos, [character(len=16) :: 'morris', &
            'morris_relative', 'tait'])
        if (cfg%sound_speed < 0.0_wp) call add('&fluid sound_speed', 'must be >= 0 (0 = automatic)')
        if (.not. (cfg%tait_gamma >= 1.0_wp)) call add('&fluid tait_gamma', 'must be >= 1')
        if (.not. (cfg%density_variation > 0.0_wp .and. cfg%density_variation < 1.0_wp)) &
            call add('&fluid density_variation', 'must lie in (0, 1)')
        if (cfg%velocity_scale < 0.0_wp) call add('&fluid velocity_scale', 'must be >= 0')
        if (cfg%length_scale < 0.0_wp) call add('&fluid length_scale', 'must be >= 0')
        call check_choice('&numerics kernel', cfg%kernel, [character(len=12) :: 'cubic', &
            'quintic', 'wendland_c2'])
        if (cfg%h_factor < 0.0_wp) call add('&numerics h_factor', &
            'must be >= 0 (0 = kernel default)')
        call check_choice('&numerics density_method', cfg%density_method, &
            [character(len=12) :: 'continuity', 'summation'])
        call check_choice('&numerics viscosity_model', cfg%viscosity_model, &
            [character(len=12) :: 'morris', 'strain_rate'])
        call check_choice('&numerics viscosity_normalisation', cfg%viscosity_normalisation, &
            [character(len=12) :: 'lattice', 'none'])
        call check_choice('&numerics wall_model', cfg%wall_model, &
            [character(len=16) :: 'morris', 'repulsive', 'mirror', 'repulsive_mirror'])
        if (.not. (cfg%cfl > 0.0_wp .and. cfg%cfl <= 1.0_wp)) call add('&numerics cfl', &
            'must lie in (0, 1]')
        if (.not. (cfg%viscous_safety > 0.0_wp .and. cfg%viscous_safety <= 0.5_wp)) &
            call add('&numerics viscous_safety', 'must lie in (0, 0.5]')
        if (.not. (cfg%force_safety > 0.0_wp .and. cfg%force_safety <= 1.0_wp)) &
            call add('&numerics force_safety', 'must lie in (0, 1]')
        if (.not. (cfg%beta_max >= 1.0_wp)) call add('&numerics beta_max', 'must be >= 1')
        if (cfg%repulsive_strength < 0.0_wp) call add('&numerics repulsive_strength', &
            'must be >= 0')
        if (cfg%repulsive_r0 < 0.0_wp) call add('&numerics repulsive_r0', 'must be >= 0')
        if (cfg%repulsive_n1 <= cfg%repulsive_n2 .or. cfg%repulsive_n2 < 1) &
            call add('&numerics repulsive_n1, repulsive_n2', 'need n1 > n2 >= 1')
        if (.not. (cfg%rebalance_threshold >= 1.0_wp)) &
            call add('&parallel rebalance_threshold', 'must be >= 1 (max load / mean load)')
        if (cfg%rebalance_check_interval < 1) &
            call add('&parallel rebalance_check_interval', 'must be >= 1 (steps)')
        if (cfg%checkpoint_interval_steps < 0) &
            call add('&restart checkpoint_interval_steps', 'must be >= 0 (0 = only at the end)')
        if (cfg%checkpoint_interval_wall < 0.0_wp) &
            call add('&restart checkpoint_interval_wall', 'must be >= 0 (s; 0 = off)')
        if (cfg%checkpoints_kept < 1) call add('&restart checkpoints_kept', 'must be >= 1')
        if (trim(cfg%viscosity_model) == 'strain_rate' .and. &
            (trim(cfg%wall_model) == 'mirror' .or. trim(cfg%wall_model) == 'repulsive_mirror')) &
            call add('&numerics viscosity_model', &
            "'strain_rate' works with wall_model = 'morris' only " // &
            '(mirror images do not carry a ' // &
            'consistent strain rate)')
        if (stat == 0) call check_analytic_case(cfg)
    contains
        subroutine add(key, what)
            character(len=*), intent(in) :: key, what
            if (stat == 0) then
                errmsg = 'invalid input in ' // cfg%source_file // ':'
            end if
            stat = stat + 1
            errmsg = errmsg // new_line('a') // '  ' // key // ': ' // what
        end subroutine add

        subroutine check_choice(key, value, allowed)
            character(len=*), intent(in) :: key, value
            character(len=*), intent(in) :: allowed(:)
            integer :: i
            character(len=:), allocatable :: list
            do i = 1, size(allowed)
                if (trim(value) == trim(allowed(i))) return
            end do
            list = "'" // trim(allowed(1)) // "'"
            do i = 2, size(allowed)
                list = list // ", '" // trim(allowed(i)) // "'"
            end do
            call add(key, "'" // trim(value) // "' is not one of " // list)
        end subroutine check_choice

        !> The analytic reference only makes sense for the channel it describes.
        subroutine check_analytic_case(c)
            type(config_t), intent(in) :: c
            if (c%analytic == 'none') return
            if (c%boundary(1) /= 'periodic' .or. c%boundary(3) /= 'wall' .or. &
                c%boundary(4) /= 'wall') &
                call add('&run analytic', "'" // trim(c%analytic) // &
                    "' needs periodic x faces " // &
                    'and walls at ylo and yhi')
            if (c%dimension == 3 .and. c%boundary(5) /= 'periodic') &
                call add('&run analytic', 'in 3D the z faces must be periodic')
            if (any(c%wall_velocity(:, 3) /= 0.0_wp)) &
                call add('&run analytic', 'the analytic channel has a resting lower wall')
            if (c%analytic == 'poiseuille' .and. any(c%wall_velocity(:, 4) /= 0.0_wp)) &
                call add('&run analytic', "'poiseuille' needs a resting upper wall")
            if (c%analytic == 'couette' .and. any(c%wall_velocity(2:3, 4) /= 0.0_wp)) &
                call add('&run analytic', "'couette' needs the upper wall to move along x only")
            if (any(c%body_force(2:3) /= 0.0_wp)) &
                call add('&run analytic', 'the analytic channel has a body force along x only')
        end subroutine check_analytic_case
    end subroutine config_validate

    !> Choices are compared in lower case; store them that way.
    subroutine lower_names(cfg)
        type(config_t), intent(inout) :: cfg
        integer :: f
        cfg%analytic = to_lower(cfg%analytic)
        cfg%eos = to_lower(cfg%eos)
        cfg%kernel = to_lower(cfg%kernel)
        cfg%density_method = to_lower(cfg%density_method)
        cfg%viscosity_model = to_lower(cfg%viscosity_model)
        cfg%viscosity_normalisation = to_lower(cfg%viscosity_normalisation)
        cfg%wall_model = to_lower(cfg%wall_model)
        do f = 1, n_faces
            cfg%boundary(f) = to_lower(cfg%boundary(f))
        end do
    end subroutine lower_names

    !> The fully resolved configuration as namelist text (defaults included).
    function config_to_text(cfg) result(text)
        type(config_t), intent(in) :: cfg
        character(len=:), allocatable :: text
        integer :: unit, g, stat
        character(len=1024) :: line

        call config_to_scratch(cfg)
        open(newunit=unit, status='scratch', action='readwrite', form='formatted', &
            delim='apostrophe')
        do g = 1, size(known_groups)
            select case (trim(known_groups(g)))
            case ('run');      write(unit, nml=run)
            case ('output');   write(unit, nml=output)
            case ('domain');   write(unit, nml=domain)
            case ('fluid');    write(unit, nml=fluid)
            case ('numerics'); write(unit, nml=numerics)
            case ('parallel'); write(unit, nml=parallel)
            case ('restart');  write(unit, nml=restart)
            end select
        end do
        rewind(unit)
        text = ''
        do
            read(unit, '(a)', iostat=stat) line
            if (stat /= 0) exit
            text = text // squeeze_padding(trim(line)) // new_line('a')
        end do
        close(unit)
    end function config_to_text

    !> Namelist output pads strings to their declared length; drop the padding before quotes.
    pure function squeeze_padding(line) result(out)
        character(len=*), intent(in) :: line
        character(len=:), allocatable :: out
        integer :: i, j
        out = ''
        i = 1
        do while (i <= len(line))
            if (line(i:i) == ' ') then
                j = i
                do while (j < len(line))
                    if (line(j + 1:j + 1) /= ' ') exit
                    j = j + 1
                end do
                if (j < len(line) .and. j > i) then
                    if (line(j + 1:j + 1) == "'") then
                        i = j + 1
                        cycle
                    end if
                end if
            end if
            out = out // line(i:i)
            i = i + 1
        end do
    end function squeeze_padding

    subroutine config_to_scratch(cfg)
        type(config_t), intent(in) :: cfg
        case_name = cfg%case_name; t_end = cfg%t_end; max_steps = cfg%max_steps
        log_interval = cfg%log_interval; analytic = cfg%analytic
        output_dir = cfg%output_dir; output_interval = cfg%output_interval
        output_times = cfg%output_times
        dimension = cfg%dimension; box_lo = cfg%box_lo; box_hi = cfg%box_hi
        boundary = cfg%boundary; wall_velocity = cfg%wall_velocity; dx = cfg%dx
        rho0 = cfg%rho0; nu = cfg%nu; body_force = cfg%body_force; eos = cfg%eos
        sound_speed = cfg%sound_speed; tait_gamma = cfg%tait_gamma
        density_variation = cfg%density_variation; velocity_scale = cfg%velocity_scale
        length_scale = cfg%length_scale
        kernel = cfg%kernel; h_factor = cfg%h_factor; density_method = cfg%density_method
        viscosity_model = cfg%viscosity_model; wall_model = cfg%wall_model; cfl = cfg%cfl
        viscosity_normalisation = cfg%viscosity_normalisation
        viscous_safety = cfg%viscous_safety; force_safety = cfg%force_safety
        beta_max = cfg%beta_max; repulsive_strength = cfg%repulsive_strength
        repulsive_r0 = cfg%repulsive_r0; repulsive_n1 = cfg%repulsive_n1
        repulsive_n2 = cfg%repulsive_n2
        rebalance_threshold = cfg%rebalance_threshold
        rebalance_check_interval = cfg%rebalance_check_interval
        checkpoint_interval_steps = cfg%checkpoint_interval_steps
        checkpoint_interval_wall = cfg%checkpoint_interval_wall
        checkpoints_kept = cfg%checkpoints_kept
    end subroutine config_to_scratch

    subroutine scratch_to_config(cfg)
        type(config_t), intent(inout) :: cfg
        cfg%case_name = case_name; cfg%t_end = t_end; cfg%max_steps = max_steps
        cfg%log_interval = log_interval; cfg%analytic = analytic
        cfg%output_dir = output_dir; cfg%output_interval = output_interval
        cfg%output_times = output_times
        cfg%dimension = dimension; cfg%box_lo = box_lo; cfg%box_hi = box_hi
        cfg%boundary = boundary; cfg%wall_velocity = wall_velocity; cfg%dx = dx
        cfg%rho0 = rho0; cfg%nu = nu; cfg%body_force = body_force; cfg%eos = eos
        cfg%sound_speed = sound_speed; cfg%tait_gamma = tait_gamma
        cfg%density_variation = density_variation; cfg%velocity_scale = velocity_scale
        cfg%length_scale = length_scale
        cfg%kernel = kernel; cfg%h_factor = h_factor; cfg%density_method = density_method
        cfg%viscosity_model = viscosity_model; cfg%wall_model = wall_model; cfg%cfl = cfl
        cfg%viscosity_normalisation = viscosity_normalisation
        cfg%viscous_safety = viscous_safety; cfg%force_safety = force_safety
        cfg%beta_max = beta_max; cfg%repulsive_strength = repulsive_strength
        cfg%repulsive_r0 = repulsive_r0; cfg%repulsive_n1 = repulsive_n1
        cfg%repulsive_n2 = repulsive_n2
        cfg%rebalance_threshold = rebalance_threshold
        cfg%rebalance_check_interval = rebalance_check_interval
        cfg%checkpoint_interval_steps = checkpoint_interval_steps
        cfg%checkpoint_interval_wall = checkpoint_interval_wall
        cfg%checkpoints_kept = checkpoints_kept
    end subroutine scratch_to_config
end module sph_config
