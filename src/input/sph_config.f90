!> Run-time configuration: the aggregate of every owner's input, one component per namelist
!> group (cfg%fluid%rho0, cfg%domain%dx, ...). Each key is declared once, in its owner's reader
!> (type, default, range, unit, meaning); this module only parses the text (sph_namelist),
!> hands each group to its owner, and collects every error into one message.
!>
!> Rank 0 reads the file; its text is broadcast and every rank parses the same text, so every
!> rank reaches the same verdict and a bad input stops collectively with one message.
module sph_config
    use sph_kinds, only: wp
    use sph_namelist, only: nml_file_t, nml_group_t, nml_key_t, nml_parse
    use sph_run_input, only: run_input_t, output_input_t, read_run_input, read_output_input
    use sph_domain_input, only: domain_input_t, read_domain_input, check_analytic_channel, &
        misfit_axis, n_faces, face_names, lattice_coordinate_text
    use sph_physics_input, only: fluid_input_t, numerics_input_t, read_fluid_input, &
        read_numerics_input, check_moving_corners, check_transport_background
    use sph_parallel_input, only: parallel_input_t, read_parallel_input
    use sph_restart_input, only: restart_input_t, read_restart_input
    use sph_health_input, only: health_input_t, read_health_input
    use sph_remesh_input, only: remesh_input_t, read_remesh_input
    use sph_body_input, only: body_input_t, read_body_inputs, check_body_wall_model
    use sph_kernel, only: kernel_support_factor, kernel_default_h_factor, kernel_id_from_name
    use sph_refinement_input, only: refinement_input_t, region_input_t, &
        read_refinement_input, read_region_inputs, check_refinement
    implicit none
    private
    public :: config_t, config_parse, config_to_text, config_read_file, config_keys
    public :: n_faces, face_names, known_groups, list_groups

    !> Groups given once (or left out), in the order they are read and written back.
    character(len=10), parameter :: known_groups(10) = [character(len=10) :: &
        'run', 'output', 'domain', 'fluid', 'numerics', 'parallel', 'restart', 'health', &
        'remesh', 'refinement']
    !> Groups that may be given several times (their owner reads a list), written back after
    !> the others: &body, one per solid body inside the box; &region, one per refinement
    !> region.
    character(len=10), parameter :: list_groups(2) = [character(len=10) :: 'body', 'region']

    !> The resolved run configuration (defaults filled in, validated); set by config_parse
    !> only, so its resolved text always matches it.
    type :: config_t
        type(run_input_t) :: run
        type(output_input_t) :: output
        type(domain_input_t) :: domain
        type(fluid_input_t) :: fluid
        type(numerics_input_t) :: numerics
        type(parallel_input_t) :: parallel
        type(restart_input_t) :: restart
        type(health_input_t) :: health
        type(remesh_input_t) :: remesh
        type(body_input_t), allocatable :: bodies(:)   !< &body groups, in file order
        type(refinement_input_t) :: refinement
        type(region_input_t), allocatable :: regions(:)   !< &region groups, in file order
        character(len=:), allocatable :: source_file
        character(len=:), allocatable :: resolved   !< namelist text of every key's value
        !> notes on the input (keys given without effect, values adjusted), one a line,
        !> each starting with 'note: '; '' when none
        character(len=:), allocatable :: notes
    end type config_t

contains

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
        if (file_size > 0) then
            allocate(character(len=file_size) :: text)
            read(unit, iostat=stat, iomsg=iomsg) text
        else
            ! a pipe or another file of no size to ask (sphremesh --check /dev/stdin, a
            ! process substitution) read as empty: read to its end (fz48)
            call read_to_end(unit, text, stat, iomsg)
        end if
        close(unit)
        if (stat /= 0) errmsg = "cannot read input file '" // trim(filename) // "': " // &
            trim(iomsg)
    end subroutine config_read_file

    !> The bytes of a stream unit up to its end (one at a time: a read of a whole buffer
    !> that meets the end says not how much it read); more than MAX_BYTES is refused.
    subroutine read_to_end(unit, text, stat, iomsg)
        integer, intent(in) :: unit
        character(len=:), allocatable, intent(out) :: text
        integer, intent(out) :: stat
        character(len=*), intent(inout) :: iomsg
        integer, parameter :: MAX_BYTES = 2**28
        character(len=:), allocatable :: grown
        character :: byte
        integer :: n
        allocate(character(len=4096) :: text)
        n = 0
        do
            read(unit, iostat=stat, iomsg=iomsg) byte
            if (is_iostat_end(stat)) then
                stat = 0
                exit
            end if
            if (stat /= 0) return
            if (n == MAX_BYTES) then
                stat = 1
                iomsg = 'more than 256 MB of input'
                return
            end if
            if (n == len(text)) then
                allocate(character(len=2 * len(text)) :: grown)
                grown(1:n) = text(1:n)
                call move_alloc(grown, text)
            end if
            n = n + 1
            text(n:n) = byte
        end do
        text = text(1:n)
    end subroutine read_to_end

    !> Parse, read every group through its owner and check everything. On error stat is the
    !> number of problems and errmsg lists each, naming file, group and key. check_paths
    !> (default .true.): also ask the file system whether &output output_dir can be made;
    !> .false. for a checkpoint's stored input (its folder is the earlier run's, not this
    !> one's) and on the ranks that take rank 0's answer (load_config).
    subroutine config_parse(cfg, text, source_name, stat, errmsg, check_paths)
        type(config_t), intent(out) :: cfg
        character(len=*), intent(in) :: text, source_name
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        logical, intent(in), optional :: check_paths
        type(nml_file_t) :: file
        type(nml_group_t) :: grp(size(known_groups))
        type(nml_group_t), allocatable :: bodies(:), regions(:)
        integer :: g, n_unknown, n_direct

        cfg%source_file = source_name
        call nml_parse(text, source_name, file, stat, errmsg)
        if (stat /= 0) return
        if (size(file%groups) == 0) then   ! an empty or all-comment file: surely a mistake
            stat = 1
            errmsg = source_name // ': no namelist group (an empty file?); give at least ' // &
                'one of &' // trim(known_groups(1)) // ', &' // trim(known_groups(3)) // ', ...'
            return
        end if
        errmsg = ''
        call file%check_groups([known_groups, list_groups], list_groups, stat, errmsg)
        do g = 1, size(known_groups)
            grp(g) = file%take(trim(known_groups(g)))
        end do
        bodies = file%take_all('body')
        regions = file%take_all('region')
        call read_groups(grp, bodies, regions, cfg, groups_known=stat == 0, &
            check_paths=check_paths)
        cfg%resolved = ''
        cfg%notes = ''
        do g = 1, size(known_groups)
            call grp(g)%finish()
            stat = stat + grp(g)%n_errors
            errmsg = errmsg // grp(g)%errors
            cfg%notes = cfg%notes // grp(g)%notes
            ! &refinement means nothing without &region (and is refused alone): left out
            if (trim(known_groups(g)) == 'refinement' .and. size(regions) == 0) cycle
            cfg%resolved = cfg%resolved // grp(g)%to_text()
        end do
        do g = 1, size(bodies)
            call bodies(g)%finish()
            stat = stat + bodies(g)%n_errors
            errmsg = errmsg // bodies(g)%errors
            cfg%notes = cfg%notes // bodies(g)%notes
            cfg%resolved = cfg%resolved // bodies(g)%to_text()
        end do
        do g = 1, size(regions)
            call regions(g)%finish()
            stat = stat + regions(g)%n_errors
            errmsg = errmsg // regions(g)%errors
            cfg%notes = cfg%notes // regions(g)%notes
            cfg%resolved = cfg%resolved // regions(g)%to_text()
        end do
        ! a misspelt key leaves its default, and the checks that read it then speak of a
        ! value nobody wrote ('ddx' gave two messages on the box's spacings before the
        ! unknown key): the unknown keys alone, as for an unknown group (fz48)
        n_unknown = sum(grp%n_unknown) + sum(bodies%n_unknown) + sum(regions%n_unknown)
        n_direct = sum(grp%n_direct) + sum(bodies%n_direct) + sum(regions%n_direct)
        if (n_unknown > 0) then
            errmsg = all_groups(.true.) // new_line('a') // '  (the other checks are made ' // &
                'once the unknown keys are put right)'
            stat = n_unknown
        else if (n_direct > 0) then
            ! likewise a value refused (not a number, not a choice, out of range): the
            ! checks across keys read its default ('walll' in boundary added 'both faces
            ! of an axis are periodic or neither', fz48)
            errmsg = all_groups(.false.)
            if (n_direct < stat) errmsg = errmsg // new_line('a') // &
                '  (the checks across keys are made once these values are put right)'
            stat = n_direct
        end if
        if (stat /= 0) errmsg = 'invalid input in ' // source_name // ':' // errmsg
        ! (each group's notes start with a new line; the first one is dropped)
        if (len(cfg%notes) > 0) cfg%notes = cfg%notes(2:)

    contains

        !> Every group's unknown-key errors (unknown) or value errors, in file order.
        function all_groups(unknown) result(text)
            logical, intent(in) :: unknown
            character(len=:), allocatable :: text
            text = ''
            do g = 1, size(known_groups)
                text = text // part(grp(g), unknown)
            end do
            do g = 1, size(bodies)
                text = text // part(bodies(g), unknown)
            end do
            do g = 1, size(regions)
                text = text // part(regions(g), unknown)
            end do
        end function all_groups

        !> One group's unknown-key errors or value errors ('' when it has none).
        function part(group, unknown) result(text)
            type(nml_group_t), intent(in) :: group
            logical, intent(in) :: unknown
            character(len=:), allocatable :: text
            text = ''
            if (unknown .and. group%n_unknown > 0) text = group%unknown
            if (.not. unknown .and. group%n_direct > 0) text = group%direct
        end function part
    end subroutine config_parse

    !> The fully resolved configuration as namelist text (defaults included), readable by
    !> config_parse and by f90nml.
    function config_to_text(cfg) result(text)
        type(config_t), intent(in) :: cfg
        character(len=:), allocatable :: text
        text = cfg%resolved
    end function config_to_text

    !> Hand each group to its owner, then the checks that span groups. groups_known = .false.:
    !> the file has a group of an unknown name (a misspelt `&fluids`), whose keys the checks
    !> across groups would miss: they are left until it is put right (with `&fluids
    !> body_force = ...`, the analytic channel was refused for want of a body force).
    subroutine read_groups(grp, bodies, regions, cfg, groups_known, check_paths)
        type(nml_group_t), intent(inout) :: grp(:), bodies(:), regions(:)
        type(config_t), intent(inout) :: cfg
        logical, intent(in), optional :: groups_known, check_paths
        call read_run_input(grp(1), cfg%run)
        call read_output_input(grp(2), cfg%run%t_end, cfg%run%max_steps, cfg%run%case_name, &
            cfg%output, check_paths)
        call read_domain_input(grp(3), cfg%domain)
        call read_fluid_input(grp(4), cfg%fluid)
        call read_numerics_input(grp(5), cfg%numerics)
        call read_parallel_input(grp(6), cfg%parallel)
        call read_restart_input(grp(7), cfg%restart)
        call read_health_input(grp(8), cfg%health)
        call read_remesh_input(grp(9), cfg%remesh)
        call read_body_inputs(bodies, cfg%domain, cfg%bodies)
        call read_refinement_input(grp(10), cfg%refinement)
        call read_region_inputs(regions, cfg%domain, cfg%bodies, cfg%regions)
        if (present(groups_known)) then
            if (.not. groups_known) return
        end if
        if (sum(grp%n_errors) == 0) call check_body_wall_model(bodies, cfg%bodies, &
            cfg%numerics%wall_model)
        if (grp(4)%n_errors == 0 .and. grp(5)%n_errors == 0) &
            call check_transport_background(grp(4), cfg%numerics, cfg%fluid)
        if (sum(grp%n_errors) == 0) call check_moving_corners(grp(5), grp(4), cfg%domain, &
            cfg%numerics, cfg%fluid)
        ! (a 2D flow has no third component: given, it moved nothing)
        if (cfg%domain%dimension == 2 .and. abs(cfg%fluid%body_force(3)) > 0.0_wp) &
            call grp(4)%error('body_force(3)', 'must be 0: a 2D run (&domain dimension = ' // &
            '2) has no third component')
        ! repulsive walls push along their normal only (free slip): moving walls drove no
        ! fluid (a Couette flow stayed at rest, 100 % off the analytic solution)
        ! (the wall faces only, after &domain's own refusals of velocities for faces that
        ! are not walls)
        if (trim(cfg%numerics%wall_model) == 'repulsive' .and. grp(3)%n_errors == 0) then
            ! (no short circuit in Fortran: the faces of a refused dimension are not read)
            if (any(abs(cfg%domain%wall_velocity(:, 1:2 * min(max(cfg%domain%dimension, 2), &
                3))) > 0.0_wp)) call grp(5)%error('wall_model', &
                "'repulsive' walls push along their normal only (free slip) and drag no " // &
                "fluid, so the moving walls of &domain wall_velocity would move nothing; " // &
                "use 'morris', 'mirror' or 'repulsive_mirror'")
        end if
        ! (found at set-up before, after the resolved input, naming neither axis nor sizes)
        if (grp(3)%n_errors == 0 .and. grp(5)%n_errors == 0) call check_periodic_sides()
        if (sum(grp%n_errors) == 0) call check_analytic_channel(grp(1), cfg%run%analytic, &
            cfg%domain, cfg%fluid%body_force)
        ! (the references' series divide by the viscosity: nu = 0 trapped at the first snapshot)
        if (sum(grp%n_errors) == 0 .and. trim(cfg%run%analytic) /= 'none' .and. &
            .not. cfg%fluid%nu > 0.0_wp) call grp(1)%error('analytic', "'" // &
            trim(cfg%run%analytic) // "' describes a viscous flow: it needs &fluid nu > 0 " // &
            "(or analytic = 'none')")
        ! the references' walls hold the fluid (no slip); repulsive walls alone let it slip
        ! (Poiseuille reported 1005 % off, with no word; fz41)
        if (sum(grp%n_errors) == 0 .and. trim(cfg%run%analytic) /= 'none' .and. &
            trim(cfg%numerics%wall_model) == 'repulsive') call grp(1)%error('analytic', "'" // &
            trim(cfg%run%analytic) // "' describes walls without slip, but &numerics " // &
            "wall_model = 'repulsive' lets the fluid slip along them; use a no-slip wall " // &
            "model ('morris', 'mirror' or 'repulsive_mirror') or analytic = 'none'")
        ! the analytic references describe an empty channel
        if (sum(grp%n_errors) == 0 .and. trim(cfg%run%analytic) /= 'none' .and. &
            size(bodies) > 0) call grp(1)%error('analytic', "'" // trim(cfg%run%analytic) // &
            "' describes an empty channel, but the input has &body groups; use " // &
            "analytic = 'none'")
        ! the transition zones' virtual particles carry no transport velocity
        if (cfg%numerics%transport_velocity .and. size(regions) > 0) call grp(5)%error( &
            'transport_velocity', '.true. works with one resolution level only (no ' // &
            '&region groups)')
        ! the first coarsening's lattice must fill the box (a later one that cannot is skipped
        ! with a warning)
        if (sum(grp%n_errors) == 0 .and. trim(cfg%remesh%mode) == 'coarsen') then
            if (misfit_axis(cfg%domain, 2.0_wp * cfg%domain%dx) /= 0) call grp(9)%error( &
                'mode', "'coarsen' needs every box length to be a whole multiple of 2 dx " // &
                '(the coarse lattice must close periodically and sit symmetrically ' // &
                'between walls)')
            ! nor could a run go on where the coarse kernel's support exceeds half a periodic
            ! side: every remesh was skipped with a warning, and --check said nothing
            if (grp(9)%n_errors == 0) call check_coarse_support()
        end if
        if (sum(grp%n_errors) == 0 .and. sum(bodies%n_errors) == 0 .and. &
            sum(regions%n_errors) == 0) call check_refinement(grp(10), regions, grp(3), &
            grp(5), grp(9), cfg%refinement, cfg%regions, cfg%domain, cfg%numerics, cfg%remesh)
    contains

        !> A periodic side must hold two kernel supports: a particle would otherwise meet
        !> its own periodic image within its support.
        subroutine check_periodic_sides()
            character(len=16) :: support, side
            integer :: axis
            real(wp) :: dx, shortest
            dx = cfg%domain%dx
            if (.not. dx > 0.0_wp) return
            do axis = 1, min(max(cfg%domain%dimension, 2), 3)
                if (.not. cfg%domain%is_periodic(axis)) cycle
                if (cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis) >= &
                    2.0_wp * kernel_support_at(dx)) cycle
                write(support, '(es10.3)') kernel_support_at(dx)
                write(side, '(es10.3)') cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)
                ! the box_hi of the shortest side of whole spacings that holds two supports
                shortest = cfg%domain%box_lo(axis) + dx * &
                    real(ceiling(2.0_wp * kernel_support_at(dx) / dx - 1.0e-9_wp), wp)
                call grp(3)%error('box_hi(' // achar(iachar('0') + axis) // ')', &
                    'the periodic side on axis ' // achar(iachar('0') + axis) // ' is ' // &
                    trim(adjustl(side)) // ' m, less than two kernel supports (2 x ' // &
                    trim(adjustl(support)) // ' m at dx with &numerics kernel and ' // &
                    'h_factor), so a particle would meet its own image; box_hi(' // &
                    achar(iachar('0') + axis) // ') = ' // &
                    lattice_coordinate_text(shortest, cfg%domain%box_lo(axis), dx) // &
                    ' m or more, or a smaller dx')
            end do
        end subroutine check_periodic_sides

        !> &remesh mode = 'coarsen': the kernel's support at 2 dx must not exceed half a
        !> periodic side (as at set-up at dx).
        subroutine check_coarse_support()
            character(len=16) :: support, side
            integer :: axis
            do axis = 1, cfg%domain%dimension
                if (.not. cfg%domain%is_periodic(axis)) cycle
                if (cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis) >= &
                    2.0_wp * kernel_support_at(2.0_wp * cfg%domain%dx)) cycle
                write(support, '(es10.3)') kernel_support_at(2.0_wp * cfg%domain%dx)
                write(side, '(es10.3)') cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)
                call grp(9)%error('mode', "'coarsen': the kernel support at 2 dx (" // &
                    trim(adjustl(support)) // ' m) would exceed half the periodic box on ' // &
                    'axis ' // achar(iachar('0') + axis) // ' (' // trim(adjustl(side)) // &
                    " m), so no remesh could be made; use a larger box or mode = 'same'")
                return
            end do
        end subroutine check_coarse_support

        !> The kernel's support at spacing dx (&numerics kernel, h_factor or its default).
        real(wp) function kernel_support_at(dx) result(support)
            real(wp), intent(in) :: dx
            real(wp) :: h_factor
            integer :: id
            id = kernel_id_from_name(cfg%numerics%kernel)
            h_factor = cfg%numerics%h_factor
            if (h_factor <= 0.0_wp) h_factor = kernel_default_h_factor(id)
            support = kernel_support_factor(id) * h_factor * dx
        end function kernel_support_at
    end subroutine read_groups

    !> Every key the code declares (group, key, type, default, range, unit, meaning).
    function config_keys() result(keys)
        type(nml_key_t), allocatable :: keys(:)
        type(nml_file_t) :: file
        type(config_t) :: cfg
        type(nml_group_t) :: grp(size(known_groups)), lists(size(list_groups))
        integer :: stat, g
        character(len=:), allocatable :: errmsg
        call nml_parse('', 'defaults', file, stat, errmsg)
        do g = 1, size(known_groups)
            grp(g) = file%take(trim(known_groups(g)))
        end do
        ! one empty instance of each repeated group declares its keys
        do g = 1, size(list_groups)
            lists(g) = file%take(trim(list_groups(g)))
        end do
        call read_groups(grp, lists(1:1), lists(2:2), cfg)
        allocate(keys(0))
        do g = 1, size(known_groups)
            keys = [keys, grp(g)%keys]
        end do
        do g = 1, size(list_groups)
            keys = [keys, lists(g)%keys]
        end do
    end function config_keys
end module sph_config
