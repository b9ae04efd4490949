!> Set-up and restart of a simulation: the particles laid or read (a checkpoint, a uniform one
!> refined where the input has regions), the levels' bookkeeping started, the set-up's log.
!> Split from sph_stepper so that each file holds one concern; the interfaces and their
!> documentation are in sph_stepper.
submodule (sph_stepper) sph_stepper_setup
    use sph_domain, only: domain_owner
    use sph_mpi_env, only: rank0_flag
    use sph_logger, only: log_warn, int_text, sci_text
    use sph_text_lines, only: next_line
    use sph_filesystem, only: text_buffer_t
    use sph_snapshot, only: read_snapshot_header
    use sph_checkpoint, only: stored_spacing, checkpoint_names
    use sph_initial, only: lattice_mass_factor
    use sph_particles, only: KIND_WALL
    use sph_physics, only: WALLS_MORRIS
    use sph_walls, only: body_holds_site
    use sph_rates, only: local_max_speed
    implicit none

contains

    !> The automatic sound speed is made for the input's velocity scale (walls, bodies, body
    !> force: sph_physics); a particle file's flow may be faster (a developed profile given as
    !> the start of a slower run: doc/output.md's example, 0.01 m/s in a channel of 2.5e-5
    !> m/s, stopped at its first step as faster than the sound speed). Refused, naming the
    !> key, when its fastest fluid particle exceeds the scale by more than 10 % (collective).
    subroutine check_file_speeds(sim, env, cfg)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        real(wp) :: fastest
        if (cfg%fluid%sound_speed > 0.0_wp .or. cfg%fluid%velocity_scale > 0.0_wp) return
        fastest = global_max(env, local_max_speed(sim%p, .false.))
        if (fastest > 1.1_wp * sim%phys%velocity_scale) call fatal_collective('set-up', &
            "&domain initial_particles: the file's fastest fluid particle moves at " // &
            sci_text(fastest, 4) // ' m/s, above the velocity scale of the automatic ' // &
            'sound speed (' // sci_text(sim%phys%velocity_scale, 4) // ' m/s, from the ' // &
            'walls, bodies and body force: c = ' // sci_text(sim%phys%c, 4) // ' m/s); ' // &
            'give &fluid velocity_scale (at least ' // sci_text(fastest, 4) // &
            ') or sound_speed')
    end subroutine check_file_speeds

    module procedure simulation_setup
        integer :: stat
        integer, allocatable :: order(:)
        character(len=:), allocatable :: errmsg
        character(len=160) :: line
        call setup_common(sim, env, cfg)
        if (len_trim(cfg%domain%initial_particles) == 0) call check_lattice_size(sim, env)
        if (lattice_mass_factor(cfg, sim%phys) /= 1.0_wp) then
            write(line, '(a,f8.5,a)') "summation density: the lattice's masses are rho0 " // &
                'dx^dim / ', 1.0_wp / lattice_mass_factor(cfg, sim%phys), ' (its kernel ' // &
                'sum times dx^dim), so that it starts at rho0'
            call log_info(trim(line))
        end if
        if (len_trim(cfg%domain%initial_particles) > 0) then
            ! rows shared evenly over the ranks, then partitioned as on a restart
            call read_initial_particles(env, cfg, sim%phys, sim%solids, &
                trim(cfg%domain%initial_particles), sim%p, stat, errmsg)
            if (stat /= 0) call fatal_collective('set-up', errmsg)
            call check_file_speeds(sim, env, cfg)
            call log_info('particles: read from ' // trim(cfg%domain%initial_particles))
        else if (multires(sim)) then
            call create_level_particles(env, cfg, sim%level_phys, sim%solids, sim%domain, &
                sim%zones, sim%p, sim%reference_mass)
            if (cfg%refinement%conserve) then
                ! the fluid's mass as the uniform lattice holds it (sph_level_balance)
                call hold_real_mass(sim, env)
                write(line, '(a,es16.9,a,f10.7,a)') 'set-up: real fluid mass ', &
                    sim%reference_mass, ' kg, the fluid''s (the levels'' lattices held ', &
                    1.0_wp - sim%mass_restored / sim%reference_mass, ' of it)'
                call log_info(trim(line))
                sim%mass_restored = 0.0_wp
            else
                sim%reference_mass = 0.0_wp
            end if
        else
            call create_lattice_particles(cfg, sim%phys, sim%solids, sim%domain, sim%p)
        end if
        if (len_trim(cfg%domain%initial_particles) == 0) call check_bodies_hold_sites(sim, &
            env, cfg)
        ! balance by particle count (walls included: they cost work too)
        call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
        call migrate(sim, env)
        ! each rank's particles in id order before the cell sort: the start then depends only
        ! on the set of particles, not on how they came (lattice, file, any reading layout)
        allocate(order(sim%p%n_owned))
        call id_order(sim%p%id, sim%p%n_owned, order)
        call particles_gather(sim%p, order)
        call halo_setup(sim%halo, sim%domain, halo_reach(sim))
        call simulation_prepare_neighbours(sim, env)
        if (len_trim(cfg%domain%initial_particles) > 0) call check_file_gaps(sim, env, cfg)
        call start_levels(sim, env)
        call log_setup(sim, env)
    end procedure simulation_setup

    !> A particle file whose fluid particles sit on top of each other (two at one place, a
    !> row written twice with new ids) ran without a word: the pair's forces vanish at r = 0
    !> and the two move as one particle of twice the mass. Refused when any fluid particle
    !> lies within COINCIDENT_GAP dx of another (no SPH arrangement holds such a pair; the
    !> neighbour list holds every pair within the support, periodic images included).
    subroutine check_file_gaps(sim, env, cfg)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        real(wp), parameter :: COINCIDENT_GAP = 0.01_wp
        integer(i8) :: n_close, first
        real(wp) :: gap2
        integer :: i, k, j
        gap2 = (COINCIDENT_GAP * cfg%domain%dx)**2
        n_close = 0
        first = huge(1_i8)
        do i = 1, sim%p%n_owned
            if (sim%p%kind(i) /= KIND_FLUID) cycle
            do k = sim%nl%start(i), sim%nl%start(i + 1) - 1
                j = sim%nl%index(k)
                if (sim%p%kind(j) /= KIND_FLUID) cycle
                if (sum((sim%p%x(:, i) - sim%p%x(:, j))**2) >= gap2) cycle
                n_close = n_close + 1
                first = min(first, sim%p%id(i), sim%p%id(j))
                exit
            end do
        end do
        n_close = global_sum(env, n_close)
        if (n_close == 0) return
        first = -global_max(env, -first)
        call fatal_collective('set-up', "&domain initial_particles: the file '" // &
            trim(cfg%domain%initial_particles) // "' has fluid particles within " // &
            sci_text(COINCIDENT_GAP, 2) // ' dx of another (' // int_text(n_close) // &
            ' of them with a partner listed; the smallest id ' // int_text(first) // &
            '): two particles at one place move as one; remove the copies')
    end subroutine check_file_gaps

    !> Multi-resolution bookkeeping at the start of a run or restart: the next unused id and
    !> each level's real mass, the reference of the mass drift in the log (collective).
    subroutine start_levels(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        integer(i8), allocatable :: n_real(:), n_virtual(:)
        real(wp), allocatable :: momentum(:, :)
        integer :: lv
        if (.not. multires(sim)) return
        sim%next_id = global_max_id(env, sim%p%id, sim%p%n_owned)
        allocate(n_real(0:sim%zones%n_levels - 1), n_virtual(0:sim%zones%n_levels - 1))
        allocate(sim%first_level_mass(0:sim%zones%n_levels - 1))
        allocate(momentum(3, 0:sim%zones%n_levels - 1))
        call level_totals(env, sim%p, sim%zones%n_levels, n_real, n_virtual, &
            sim%first_level_mass, momentum)
        ! a region that holds no site of its level's lattice (inside a body, or a band thinner
        ! than half a spacing) makes a level of virtual particles only, and one that covers
        ! all of the fluid leaves level 0 none: the run went on without a word
        do lv = 0, sim%zones%n_levels - 1
            if (n_real(lv) > 0) cycle
            if (lv == 0) then
                call log_warn('level 0 holds no real fluid particle: the &region groups ' // &
                    'cover all of the fluid; use one resolution (dx / 2^level) instead')
            else
                call log_warn('level ' // int_text(int(lv, i8)) // ' holds no real fluid ' // &
                    'particle: its &region groups hold no site of its lattice (inside a ' // &
                    'body, or thinner than half its spacing ' // &
                    trim(sci_text(sim%level_phys(lv)%dx)) // ' m); it has virtual particles ' // &
                    'only and refines nothing')
            end if
        end do
        ! a restart has them from its checkpoint (simulation_restart)
        if (sim%reference_mass <= 0.0_wp) sim%reference_mass = sum(sim%first_level_mass)
        if (.not. allocated(sim%level_push)) then
            allocate(sim%level_push(3, 0:sim%zones%n_levels - 1), source=0.0_wp)
            allocate(sim%level_push_mass(0:sim%zones%n_levels - 1), source=0.0_wp)
        end if
    end subroutine start_levels

    module procedure simulation_restart
        character(len=:), allocatable :: path, skipped, errmsg, stored_input, index_text
        character(len=:), allocatable :: mismatch
        type(config_t) :: stored
        integer :: stat, fluid_stat, check_stat, i
        logical :: same_layout, is_directory
        character(len=256) :: line
        real(wp) :: stored_dx
        real(wp), allocatable :: balance(:), force_sums(:)
        integer :: n
        character(len=:), allocatable :: what, walls_changed
        !> the input the run goes on with: cfg, at the checkpoint's spacing when a remesh in
        !> the run changed it (take_remeshed_spacing)
        type(config_t) :: given

        what = 'restart'
        if (present(label)) what = label
        walls_changed = ''
        ! the checkpoint first: the run may go on at its spacing (given)
        is_directory = .false.
        if (env%rank == 0) inquire(file=trim(from) // '/.', exist=is_directory)
        ! (one answer for all: find_latest_checkpoint is collective)
        is_directory = rank0_flag(env, is_directory)
        if (is_directory) then
            call find_latest_checkpoint(env, from, trim(cfg%run%case_name), path, skipped, stat, &
                errmsg)
            if (stat /= 0) call fatal_collective(what, errmsg)
            ! (a warning: a newer checkpoint, truncated by a crash or damaged, is not used)
            if (len(skipped) > 0) call log_warn(what // ': newer checkpoints skipped:' // &
                skipped)
        else
            path = from
        end if
        ! (given keeps the input's resolved text, which setup_common stores and the run's
        ! files carry, with the dx it gives: the next restart takes the spacing again)
        given = cfg
        call take_remeshed_spacing(env, path, what, given)
        call setup_common(sim, env, given)
        call read_checkpoint(env, path, sim%p, sim%domain, sim%time, sim%step, stored_input, &
            index_text, same_layout, stat, errmsg, stored_dx, balance, force_sums)
        if (stat /= 0) call fatal_collective(what, errmsg)
        ! the forces file's running mean since its last row, as the checkpointed run had it
        ! (rank 0 holds the sums over the ranks; none in checkpoints written before it was
        ! kept, or for other solids: the mean then starts at the restart)
        if (size(force_sums) == 1 + size(sim%force_integral)) then
            sim%force_window = force_sums(1)
            if (env%rank == 0) sim%force_integral = reshape(force_sums(2:), &
                shape(sim%force_integral))
        end if
        ! a multi-resolution state continued by an input without regions would run its fine
        ! and virtual particles as if they were of the one level (a two-level channel did,
        ! without a word)
        if (.not. multires(sim)) then
            if (global_max(env, int(count(sim%p%level(1:sim%p%n_owned) > 0 .or. &
                sim%p%kind(1:sim%p%n_owned) == KIND_VIRTUAL), i8)) > 0) &
                call fatal_collective(what, 'the checkpoint holds a multi-resolution ' // &
                'state (particles of finer levels and virtual particles): it continues with ' // &
                'an input that has its &region groups (the input stored in it has them)')
        end if
        ! the levels' balance as the checkpointed run had it (the reference mass, and for
        ! sub-cycled levels the pushes of the levels not evaluated at the next step), and
        ! the zones' drift (checkpoints written before it was kept: none, the zones then
        ! made at the next rebuild as before)
        n = sim%zones%n_levels
        if (multires(sim) .and. (size(balance) == 1 + 4 * n .or. &
                size(balance) == 2 + 4 * n)) then
            sim%reference_mass = balance(1)
            allocate(sim%level_push(3, 0:n - 1), sim%level_push_mass(0:n - 1))
            sim%level_push(:, :) = reshape(balance(2:1 + 3 * n), [3, n])
            sim%level_push_mass(:) = balance(2 + 3 * n:1 + 4 * n)
            if (size(balance) == 2 + 4 * n) sim%zone_drift = balance(2 + 4 * n)
        end if
        ! the input the checkpoint was written with: a Verlet run's rates are those its next
        ! step starts from (a verlet continuation takes them, bit for bit; any other
        ! checkpoint's are evaluated again), and its particles (walls and bodies included)
        ! were laid for its geometry
        call config_parse(stored, stored_input, 'checkpoint input', stat, errmsg, &
            check_paths=.false.)
        ! a remeshed checkpoint keeps its input as given, with the spacing the run or the
        ! offline remesh changed to beside it (a restart gives that one, or the stored
        ! input's, taken at it above; refused below otherwise)
        if (stat == 0 .and. stored_dx > 0.0_wp) stored%domain%dx = stored_dx
        sim%rates_stale = .true.
        ! a stored input this version refuses (written before a rule was added): the given
        ! input cannot be checked against it, so a uniform state gets the given input's
        ! walls and bodies (a circle's refused velocity went on, unchecked and unsaid)
        if (stat /= 0) then
            errmsg = "the input stored in '" // path // "' is refused by this version (" // &
                one_line(errmsg) // ')'
            if (multires(sim)) call fatal_collective(what, errmsg // ': a multi-resolution ' // &
                'state cannot be checked against the given input, nor its walls laid again; ' // &
                'continue it with the version that wrote it')
            call log_warn(what // ': ' // errmsg // '; the given ' // &
                'input is not checked against it (geometry, rest density): make sure it ' // &
                'describes the same problem')
            walls_changed = 'the walls and bodies of a stored input this version refuses'
        end if
        if (stat == 0) then
            sim%rates_stale = trim(stored%numerics%integrator) /= 'verlet'
            mismatch = geometry_mismatch(stored, given)
            if (len(mismatch) > 0) call fatal_collective(what, mismatch)
            ! the particles' densities and masses are those of the stored rest density: with
            ! another, the equation of state turned them into pressures that stopped the run
            ! at its first step, as a density outside &health density_band
            if (abs(stored%fluid%rho0 - given%fluid%rho0) > 1.0e-12_wp * stored%fluid%rho0) then
                ! (all the digits: the refusal is to 1e-12, and 1000.0000001 printed as 1000)
                write(line, '(a, es24.16, a, es24.16, a)') "the checkpoint's fluid has " // &
                    '&fluid rho0 = ', stored%fluid%rho0, ' kg/m^3 but the input ', &
                    given%fluid%rho0, ' kg/m^3; continue with the checkpoint''s rest density'
                call fatal_collective(what, trim(line))
            end if
            ! (a summation run's masses follow its kernel: kept, the densities start off)
            mismatch = masses_mismatch(stored, given)
            if (len(mismatch) > 0) call log_warn(what // ": the checkpoint's masses were " // &
                'made for its own input (' // mismatch // '): the particles keep them, and ' // &
                'the densities start off rho0 by their ratio')
            walls_changed = walls_mismatch(stored, given)
            if (len(walls_changed) > 0 .and. allocated(stored%regions)) then
                if (size(stored%regions) > 0) call fatal_collective(what, 'the input ' // &
                    'changes ' // walls_changed // ", for which the checkpoint's wall " // &
                    'particles were laid; a multi-resolution state continues with them ' // &
                    '(its input is stored in it)')
            end if
        end if
        ! values no run writes (a file edited or damaged outside sphremesh) stop here, not
        ! later as a floating-point trap, an index out of range or a hang; after the
        ! geometry's refusals: another case's checkpoint has wall particles of solids the
        ! input lacks, and was called damaged (fz38)
        call check_read_particles(env, sim%p, sim%zones%n_levels, size(sim%solids%list), &
            path, check_stat, errmsg)
        if (check_stat /= 0) call fatal_collective(what, errmsg)
        ! a remeshed (refined or coarsened) checkpoint holds particles of another spacing:
        ! the input must say so (kernel, masses of new walls, time step follow from dx),
        ! unless take_remeshed_spacing took it
        if (stored_dx > 0.0_wp .and. abs(stored_dx - given%domain%dx) > 1.0e-9_wp * stored_dx) then
            ! (at a spacing where no run can go on, that advice led to the next refusal)
            mismatch = spacing_problem_at(given, stored_dx)
            if (len(mismatch) > 0) then
                write(line, '(a,es14.8,a)') "the checkpoint's particles have spacing dx = ", &
                    stored_dx, ' m, at which no run of this input can go on'
                call fatal_collective(what, trim(line) // ' (' // mismatch // '): a remesh ' &
                    // 'wrote it for study, and no run continues it')
            end if
            write(line, '(a,es15.8,a,es15.8,a)') "the checkpoint's particles have spacing " // &
                'dx = ', stored_dx, ' m but &domain dx = ', given%domain%dx, &
                ' m; set &domain dx to the checkpoint''s spacing to continue from it'
            call fatal_collective(what, trim(line))
        end if
        ! fluid deep inside a solid (after the geometry's refusals: a moved body is said so)
        ! (its own status: stat still says whether the stored input was read, below)
        call check_fluid_outside_solids(env, sim%p, sim%solids, IN_SOLID_SLACK, path, &
            fluid_stat, errmsg)
        if (fluid_stat /= 0) call fatal_collective(what, errmsg)
        ! a checkpoint's rates are its own input's: with other physics (a body force changed
        ! to continue) the first step would kick with the old ones (checked after the
        ! refusals: a run that stops is not told that its rates will be evaluated)
        if (.not. sim%rates_stale .and. stat == 0) then
            if (rates_inputs_differ(stored, given)) then
                sim%rates_stale = .true.
                call log_info(what // ': the input differs from the checkpoint''s in what ' &
                    // 'the rates depend on; its rates are evaluated anew')
            end if
        end if
        ! (a changed force or viscosity read as an error of hundreds of percent, unexplained)
        if (stat == 0 .and. trim(given%run%analytic) /= 'none') then
            if (rates_inputs_differ(stored, given)) call log_info(what // ": &run analytic " // &
                "describes a run made with this input from t = 0, not this one's continuation " &
                // 'of a checkpoint made with another')
        end if
        if (given%remesh%every_time > 0.0_wp) sim%next_remesh_time = &
            next_multiple(sim%time, given%remesh%every_time)
        sim%snapshot_index = index_text
        if (what == 'restart') call keep_listed_snapshots(sim, env, &
            trim(given%output%output_dir))
        if (what == 'restart') call adopt_earlier_checkpoints(sim, env, path, &
            trim(given%output%output_dir), trim(given%run%case_name))
        if (.not. same_layout) then
            call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
            call migrate(sim, env)
        else if (misplaced(sim, env) > 0) then
            ! rows per rank that do not match the stored decomposition (edited outside
            ! sphremesh, though they still sum to the count): a rank would have missed the
            ! neighbours of particles outside its region
            call log_warn(what // ": the rows stored per rank in '" // path // "' do not " // &
                'match its decomposition; the particles are handed to their owners')
            call migrate(sim, env)
        end if
        ! each particle's smoothing length is its level's kernel's, the input's: an input
        ! that changes &numerics kernel or h_factor went on writing the checkpoint's (fz45)
        do i = 1, sim%p%n_owned
            sim%p%h(i) = sim%level_phys(sim%p%level(i))%kernel%h
        end do
        if (len(walls_changed) > 0) call lay_walls_again(sim, env, what, walls_changed)
        call refine_if_uniform(sim, env, what)
        call halo_setup(sim%halo, sim%domain, halo_reach(sim))
        call simulation_prepare_neighbours(sim, env)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        call start_levels(sim, env)
        ! (the path first, apart: a line of fixed length cannot hold every path)
        write(line, '(a,es12.5,a,i0,a)') ' at t = ', sim%time, ' s, step ', sim%step, &
            merge(' (same decomposition)      ', ' (decomposition rebuilt)   ', same_layout)
        if (what == 'restart') then
            call log_info('continuing from ' // path // trim(line))
        else
            ! (an offline command reads the checkpoint; nothing continues here)
            call log_info(what // ': read ' // path // trim(line))
        end if
        if (stored_input /= sim%input_text) call log_info(what // ': the input differs ' // &
            'from the one stored in the checkpoint; the new input is used')
        call log_setup(sim, env)
    end procedure simulation_restart

    !> A run continued from a checkpoint in its own output folder (a job chain's link, a
    !> restart there) goes on with the checkpoints of its case there up to that step as its
    !> own, so that &restart checkpoints_kept holds over the whole chain (each link kept its
    !> own: a 20-link chain left 21 checkpoints with checkpoints_kept = 2, fz42). A
    !> checkpoint read from elsewhere adopts nothing: what the folder holds may be another
    !> run's. Later steps' files are not this run's past (they are set aside: simulation_run).
    subroutine adopt_earlier_checkpoints(sim, env, path, folder, case_name)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path, folder, case_name
        character(len=512), allocatable :: names(:)
        integer(i8), allocatable :: steps(:)
        integer, allocatable :: mine(:), order(:)
        integer :: stat, k, cut
        cut = index(path, '/', back=.true.)
        if (cut == 0) then
            if (.not. same_folder('.', folder)) return
        else
            if (.not. same_folder(path(1:cut - 1), folder)) return
        end if
        call checkpoint_names(env, folder, case_name, names, steps, stat)
        if (stat /= 0) return
        mine = pack([(k, k = 1, size(steps))], steps <= sim%step)
        ! by step, oldest first
        allocate(order(size(mine)))
        call id_order(steps(mine), size(mine), order)
        sim%checkpoints = [character(len=512) :: (folder // '/' // trim(names(mine(order(k)))), &
            k = 1, size(mine))]
    end subroutine adopt_earlier_checkpoints

    !> Whether two folder names name one folder as the run writes them (a trailing '/', a
    !> leading './'); two spellings of one folder through links are taken as two.
    logical function same_folder(a, b)
        character(len=*), intent(in) :: a, b
        same_folder = plain(a) == plain(b)
    contains
        function plain(name) result(p)
            character(len=*), intent(in) :: name
            character(len=:), allocatable :: p
            p = trim(name)
            do while (len(p) > 2)
                if (p(1:2) /= './') exit
                p = p(3:)
            end do
            do while (len(p) > 1)
                if (p(len(p):len(p)) /= '/') exit
                p = p(1:len(p) - 1)
            end do
            if (len(p) == 0) p = '.'
        end function plain
    end function same_folder

    !> The checkpoint's snapshot index (the .xdmf series) without the snapshots that are not
    !> in `folder`: a run continued into another output_dir (from a checkpoint in an
    !> archive) listed the earlier snapshots by bare name where they are not, and its series
    !> did not open. The .xdmf names its files without a folder, so it can only list what is
    !> beside it; the log says how many it leaves out (also snapshots moved away to free
    !> space). Rank 0 looks, every rank takes its answer.
    subroutine keep_listed_snapshots(sim, env, folder)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: folder
        type(text_buffer_t) :: kept
        character(len=:), allocatable :: entry
        character(len=512) :: file_name
        character(len=32) :: number
        real(wp) :: time
        integer(i8) :: step, rows
        integer :: start, ios, dropped
        logical :: exists
        if (env%rank == 0) then
            dropped = 0
            start = 1
            do while (start <= len(sim%snapshot_index))
                call next_line(sim%snapshot_index, start, entry)
                if (len_trim(entry) == 0) cycle
                read(entry, *, iostat=ios) time, step, rows, file_name
                exists = .false.
                if (ios == 0) inquire(file=folder // '/' // trim(file_name), exist=exists)
                if (exists) then
                    call kept%put(entry // new_line('a'))
                else
                    dropped = dropped + 1
                end if
            end do
            sim%snapshot_index = ''
            if (kept%used > 0) sim%snapshot_index = kept%text(1:kept%used)
            if (dropped > 0) then
                write(number, '(i0)') dropped
                call log_warn('restart: ' // trim(number) // ' earlier snapshot(s) of the ' // &
                    "checkpoint's series are not in '" // folder // "' (continued into " // &
                    'another folder, or moved away); its .xdmf lists the snapshots that are')
            end if
        end if
        call broadcast_text(env, sim%snapshot_index)
    end subroutine keep_listed_snapshots

    !> A run that refines or coarsens in its course (&remesh) writes its later checkpoints at
    !> the new spacing (their attribute dx) with its input as given. Continued with that same
    !> input (its &domain dx the stored input's), it goes on at the checkpoint's spacing, as
    !> the run that wrote it did, and the log says so: the input's own dx was refused, and a
    !> job chain stopped at its second link. Left as it is (and so refused by
    !> simulation_restart, which names the checkpoint's spacing): an input with yet another
    !> dx; one with &region groups (their zones' width and faces are checked at the input's
    !> spacing); a spacing at which no run of the input can go on (spacing_problem_at: an
    !> offline remesh writes such a file for study only, and a run skips such a remesh).
    !> A checkpoint without a readable spacing or stored input is left to the restart's own
    !> checks. Collective.
    subroutine take_remeshed_spacing(env, path, what, given)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: path, what
        type(config_t), intent(inout) :: given
        type(config_t) :: stored
        character(len=:), allocatable :: text, errmsg
        real(wp) :: dx_file, time
        integer(i8) :: step, n_rows
        integer :: dimension, stat
        dx_file = stored_spacing(env, path)
        ! (no spacing, or none a run writes: -1; no comparison with a NaN)
        if (.not. dx_file > 0.0_wp) return
        if (abs(dx_file - given%domain%dx) <= 1.0e-9_wp * dx_file) return
        call read_snapshot_header(env, path, time, step, dimension, n_rows, text, stat, errmsg)
        if (stat /= 0) return
        call config_parse(stored, text, 'checkpoint input', stat, errmsg, &
            check_paths=.false.)
        if (stat /= 0) return
        if (abs(stored%domain%dx - given%domain%dx) > 1.0e-9_wp * stored%domain%dx) return
        if (allocated(given%regions)) then
            if (size(given%regions) > 0) return
        end if
        if (len(spacing_problem_at(given, dx_file)) > 0) return
        call log_info(what // ": the checkpoint's particles have spacing dx = " // &
            trim(sci_text(dx_file)) // ' m, remeshed from the input''s ' // &
            trim(sci_text(given%domain%dx)) // ' m: the input is taken at ' // &
            trim(sci_text(dx_file)) // ' m')
        given%domain%dx = dx_file
    end subroutine take_remeshed_spacing

    !> text on one line: its lines, their indents trimmed, joined by '; ' (by ' ' after a
    !> colon)
    function one_line(text) result(joined)
        character(len=*), intent(in) :: text
        character(len=:), allocatable :: joined, line
        integer :: start
        joined = ''
        start = 1
        do while (start <= len(text))
            call next_line(text, start, line)
            line = trim(adjustl(line))
            if (len(line) == 0) cycle
            if (len(joined) == 0) then
                joined = line
            else if (joined(len(joined):) == ':') then
                joined = joined // ' ' // line
            else
                joined = joined // '; ' // line
            end if
        end do
    end function one_line

    !> The wall and body particles laid again for the input (a uniform state): the
    !> checkpoint's were laid for its own kernel support, wall model and wall velocities,
    !> and a restart that changed them ran with the old ones (h_factor 4: 3 layers kept where
    !> 8 were needed, the density down to 940 kg/m^3 in one step; a faster lid or a moving
    !> body not moving, while the log said the new input was used). Ids after every other
    !> particle's, each made by the rank whose region holds it (as a remesh lays them).
    subroutine lay_walls_again(sim, env, what, changed)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: what, changed
        call lay_lattice_walls(sim, env)
        sim%rates_stale = .true.
        call log_info(what // ': the input changes ' // changed // '; the wall and body ' // &
            'particles were laid again for it')
    end subroutine lay_walls_again

    !> The number of particles (all ranks) that lie outside their rank's region (collective).
    !> A checkpoint is written after the particles were handed to their owners: none.
    integer(i8) function misplaced(sim, env)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        integer :: i
        integer(i8) :: n
        n = 0
        do i = 1, sim%p%n_owned
            if (domain_owner(sim%domain, sim%p%x(:, i)) /= env%rank) n = n + 1
        end do
        misplaced = global_sum(env, n)
    end function misplaced

    !> A checkpoint of a uniform run continued with &region groups: the regions are refined
    !> (sph_transition_driver refine_uniform_state) and the decomposition rebalanced.
    subroutine refine_if_uniform(sim, env, what)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: what
        integer(i8) :: before
        character(len=160) :: line
        real(wp) :: mass_before, mass_after
        if (.not. multires(sim)) return
        if (global_max(env, int(maxval(sim%p%level(1:sim%p%n_owned), &
            mask=sim%p%n_owned > 0), i8)) > 0) return
        before = global_sum(env, int(sim%p%n_owned, i8))
        mass_before = global_sum(env, real_fluid_mass(sim%p))
        sim%next_id = global_max_id(env, sim%p%id, sim%p%n_owned)
        call refine_uniform_state(env, sim%cfg, sim%level_phys, sim%solids, sim%domain, &
            sim%zones, sim%p, sim%next_id)
        ! the real fluid's mass as the uniform state held it (as every remesh does): next to
        ! a body the uniform lattice's masses were scaled to the fluid's volume, which the
        ! fine band now fills with masses of its own (Morris' cylinder, L/25 -> L/50 around
        ! it: 1.8 % more); elsewhere the two agree to round-off and nothing is scaled
        mass_after = global_sum(env, real_fluid_mass(sim%p))
        if (mass_after > 0.0_wp .and. abs(mass_after - mass_before) > 1.0e-12_wp * mass_before) &
            then
            call scale_masses(sim%p, mass_before / mass_after)
            write(line, '(a, es16.9, a)') what // ': the refined levels'' masses scaled by ', &
                mass_before / mass_after, ' to the uniform state''s total'
            call log_info(trim(line))
        end if
        ! the checkpoint's rates (a verlet run's) are those of the uniform state: the new
        ! particles have none
        sim%rates_stale = .true.
        call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
        call migrate(sim, env)
        write(line, '(a,i0,a,i0,a)') what // ': the checkpoint is uniform; its regions were ' &
            // 'refined (', before, ' -> ', global_sum(env, int(sim%p%n_owned, i8)), ' particles)'
        call log_info(trim(line))
    end subroutine refine_if_uniform

    !> Morris walls are the lattice sites inside a solid: a body that holds none (a circle
    !> of radius 0.55 dx between four sites, a plate half a spacing thick between two rows)
    !> gets no wall particle, and the run went on without it, its force exactly 0. Refused,
    !> naming the body and what would hold a site wherever it lies (collective). A body with
    !> no wall particle of its own that does hold sites (inside another body, which takes
    !> them) is the input's choice. Multi-resolution: the particles of every level count.
    subroutine check_bodies_hold_sites(sim, env, cfg)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        integer(i8), allocatable :: held(:)
        integer :: n_bodies, first, i, b
        character(len=:), allocatable :: need
        if (sim%phys%walls /= WALLS_MORRIS .or. .not. allocated(cfg%bodies)) return
        n_bodies = size(cfg%bodies)
        if (n_bodies == 0) return
        ! the bodies follow the box's planes in the solids' list, in input order
        first = size(sim%solids%list) - n_bodies
        allocate(held(n_bodies))
        held = 0_i8
        do i = 1, sim%p%n_owned
            if (sim%p%kind(i) /= KIND_WALL) cycle
            b = sim%p%solid(i) - first
            if (b >= 1 .and. b <= n_bodies) held(b) = held(b) + 1_i8
        end do
        held = global_sum(env, held)
        do b = 1, n_bodies
            if (held(b) > 0_i8) cycle
            if (body_holds_site(cfg, sim%solids, b, cfg%domain%dx)) cycle
            select case (trim(cfg%bodies(b)%shape))
            case ('circle', 'cylinder')
                need = 'a radius of at least dx / sqrt(2) (' // &
                    sci_text(cfg%domain%dx / sqrt(2.0_wp), 4) // ' m)'
            case ('sphere')
                need = 'a radius of at least dx sqrt(3) / 2 (' // &
                    sci_text(cfg%domain%dx * sqrt(3.0_wp) / 2.0_wp, 4) // ' m)'
            case default
                need = 'sides of at least dx (' // sci_text(cfg%domain%dx, 4) // ' m)'
            end select
            call fatal_collective('input', '&body ' // int_text(int(b, i8)) // " ('" // &
                trim(cfg%bodies(b)%name) // "'): the " // trim(cfg%bodies(b)%shape) // &
                ' holds no site of the particle lattice (&domain dx = ' // &
                sci_text(cfg%domain%dx, 4) // " m), so with wall_model = 'morris' it " // &
                'would have no wall particle, no effect on the flow and no force; a ' // &
                trim(cfg%bodies(b)%shape) // ' holds a site wherever it lies with ' // need)
        end do
    end subroutine check_bodies_hold_sites

    subroutine log_setup(sim, env)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=256) :: line
        integer(i8) :: counts(3)
        write(line, '(a,es12.5,a,es12.5,a,es12.5,a)') 'physics: h = ', sim%phys%kernel%h, &
            ' m (kernel ' // kernel_name(sim%phys%kernel%id) // ', support ', &
            sim%phys%kernel%support, ' m), c = ', sim%phys%c, ' m/s'
        call log_info(trim(line))
        write(line, '(a,es12.5,a,es12.5,a,i0)') '         velocity scale ', &
            sim%phys%velocity_scale, ' m/s, length scale ', sim%phys%length_scale, &
            ' m, wall layers ', wall_layers(sim%phys)
        call log_info(trim(line))
        if (sim%phys%transport_velocity) then
            write(line, '(a,es12.5,a)') '         transport velocity: background pressure ', &
                sim%phys%transport_pressure, ' Pa'
            call log_info(trim(line))
        end if
        ! (the virtual particles of a multi-resolution run apart: they were counted as real)
        counts = global_sum(env, [int(count(sim%p%kind(1:sim%p%n_owned) /= KIND_VIRTUAL), i8), &
            int(count(sim%p%kind(1:sim%p%n_owned) == KIND_FLUID), i8), &
            int(count(sim%p%kind(1:sim%p%n_owned) == KIND_VIRTUAL), i8)])
        write(line, '(a,i0,a,i0,a)') 'particles: ', counts(1), ' real (fluid ', counts(2), ')'
        if (counts(3) > 0) write(line, '(a,a,i0,a)') trim(line), ', ', counts(3), ' virtual'
        write(line, '(a,a,f6.3)') trim(line), ', load imbalance ', &
            domain_imbalance(env, sim%p%n_owned)
        call log_info(trim(line))
    end subroutine log_setup
end submodule sph_stepper_setup
