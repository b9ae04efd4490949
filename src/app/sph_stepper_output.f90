!> Reports and output files of a simulation: the forces on the solids (sum, CSV, log),
!> snapshots with their XDMF index, checkpoints, the --check report, the levels' log lines,
!> the neighbours per particle, the fluid density range and the error against the analytic
!> reference.
!> Split from sph_stepper so that each file holds one concern; the interfaces and their
!> documentation are in sph_stepper.
submodule (sph_stepper) sph_stepper_output
    use sph_logger, only: fixed_text, mb_text, int_text
    use sph_mpi_env, only: global_min
    use sph_particles, only: KIND_VIRTUAL, KIND_WALL
    use sph_memory, only: peak_resident_bytes, startup_memory_bytes
    use sph_reference, only: relative_l2_error, relative_l2_from_sums, reference_resolved, &
        UNRESOLVED, error_percent_text
    use sph_snapshot, only: write_snapshot, SNAPSHOT_NOT_CLOSED
    use sph_checkpoint, only: write_checkpoint, checkpoint_filename
    use sph_xdmf, only: xdmf_index_entry, write_xdmf
    use sph_filesystem, only: delete_file, make_directories, write_text_file, &
        write_text_file_whole, text_buffer_t, ends_with_new_line
    use sph_errors, only: STATUS_OUTPUT_FAILED
    implicit none

contains

    module procedure simulation_write_checkpoint
        character(len=:), allocatable :: path, errmsg
        real(wp), allocatable :: balance(:), force_sums(:)
        integer :: stat
        call synchronise(sim, env)
        ! a velocity-Verlet checkpoint carries the rates its next step starts from; after a
        ! remesh (or anything else that left them stale) those are evaluated now, as that
        ! step would: the checkpoint of a remesh step held zeros, and a restart from it kicked
        ! with them (velocities 0.4 % of the peak off one step later)
        if (sim%verlet .and. sim%rates_stale) then
            call evaluate_rates(sim, env)
            sim%rates_stale = .false.
        end if
        path = checkpoint_filename(trim(sim%cfg%output%output_dir), trim(sim%cfg%run%case_name), &
            sim%step)
        call checkpoint_balance(sim, balance)
        ! the forces file's running mean: the window and the integrals over the ranks (a
        ! restart from a checkpoint between two rows left the steps before it out of the
        ! next row's mean, 1.3 % of a cylinder's drag: fz45)
        force_sums = [sim%force_window, global_sum(env, reshape(sim%force_integral, &
            [size(sim%force_integral)]))]
        if (present(forces_row_follows)) then
            if (forces_row_follows) force_sums = 0.0_wp
        end if
        call write_checkpoint(env, sim%p, sim%domain, path, sim%time, sim%step, &
            sim%cfg%domain%dimension, code_version, sim%input_text, sim%snapshot_index, stat, &
            errmsg, sim%cfg%domain%dx, balance, force_sums)
        ! (stat 2: not the folder's fault)
        if (stat == 2) call fatal_collective('checkpoint', errmsg)
        if (stat /= 0) call fatal_collective('checkpoint', errmsg // ' (&output output_dir)', &
            STATUS_OUTPUT_FAILED, abort=stat == SNAPSHOT_NOT_CLOSED)
        if (all(sim%checkpoints /= path)) &
            sim%checkpoints = [character(len=512) :: sim%checkpoints, path]
        do while (size(sim%checkpoints) > sim%cfg%restart%checkpoints_kept)
            if (env%rank == 0) call delete_file(trim(sim%checkpoints(1)))
            sim%checkpoints = sim%checkpoints(2:)
        end do
        call log_info('checkpoint: ' // path)
    end procedure simulation_write_checkpoint

    module procedure checkpoint_balance
        ! (left unallocated: not present)
        if (multires(sim) .and. allocated(sim%level_push)) balance = [sim%reference_mass, &
            reshape(sim%level_push, [size(sim%level_push)]), sim%level_push_mass, &
            sim%zone_drift]
    end procedure checkpoint_balance

    module procedure simulation_solid_forces
        forces = reshape(global_sum(env, reshape(sim%wall_forces, [size(sim%wall_forces)])), &
            shape(sim%wall_forces))
    end procedure simulation_solid_forces

    module procedure simulation_write_forces
        real(wp), allocatable :: forces(:, :, :), mean(:, :, :)
        real(wp) :: window
        character(len=:), allocatable :: path, reason
        character(len=512) :: line
        type(text_buffer_t) :: rows
        integer :: k, stat
        logical :: exists
        if (size(sim%solids%list) == 0) return
        forces = simulation_solid_forces(sim, env)
        ! the mean since the last row: the pressure part of the force is noisy from step to
        ! step (the cylinder's drag samples scatter by 2-11 %), its mean over the steps is
        ! what a drag balance needs (a restart goes on with the checkpoint's sums); the
        ! force itself where no step was taken since the last row
        window = sim%force_window
        mean = forces
        if (window > 0.0_wp) mean = reshape(global_sum(env, reshape(sim%force_integral, &
            [size(sim%force_integral)])), shape(sim%force_integral)) / window
        sim%force_integral = 0.0_wp
        sim%force_window = 0.0_wp
        path = trim(sim%cfg%output%output_dir) // '/' // trim(sim%cfg%run%case_name) // &
            '_forces.csv'
        stat = 0
        reason = ''
        if (env%rank == 0) then
            ! a restart into a new output folder writes its forces before any snapshot
            call make_directories(trim(sim%cfg%output%output_dir), stat)
            inquire(file=path, exist=exists)
            if (stat /= 0) then
                reason = 'the folder cannot be made'
            else
                ! the rows appended whole or not at all (a full disk left a row cut short)
                if (fresh .or. .not. exists) call rows%put('time,step,body,Fx,Fy,Fz,' // &
                    'Fx_pressure,Fy_pressure,Fz_pressure,Fx_viscous,Fy_viscous,Fz_viscous,' // &
                    'Fx_mean,Fy_mean,Fz_mean' // new_line('a'))
                do k = 1, size(forces, 3)
                    write(line, '(es24.16,",",i0,",",a,12(",",es24.16))') sim%time, sim%step, &
                        trim(sim%solids%list(k)%name), forces(:, 1, k) + forces(:, 2, k), &
                        forces(:, 1, k), forces(:, 2, k), mean(:, 1, k) + mean(:, 2, k)
                    call rows%put(trim(line) // new_line('a'))
                end do
                if (fresh .or. .not. exists) then
                    call write_text_file_whole(path, rows%text(1:rows%used), stat, reason)
                else
                    ! a row cut short by an older run (a full disk, a crash) is not continued:
                    ! the new rows start on a line of their own
                    if (ends_with_new_line(path)) then
                        call write_text_file(path, rows%text(1:rows%used), stat, reason, &
                            append=.true.)
                    else
                        call write_text_file(path, new_line('a') // rows%text(1:rows%used), &
                            stat, reason, append=.true.)
                    end if
                end if
            end if
        end if
        if (global_max(env, int(stat, i8)) /= 0) call fatal_collective('output', &
            "cannot write the forces to '" // path // "': " // reason // &
            ' (&output output_dir; the rows before are whole)', STATUS_OUTPUT_FAILED)
    end procedure simulation_write_forces

    module procedure simulation_log_forces
        real(wp), allocatable :: forces(:, :, :)
        character(len=256) :: line
        character(len=:), allocatable :: unit_text
        integer :: k
        if (size(sim%solids%list) == 0) return
        forces = simulation_solid_forces(sim, env)
        unit_text = merge(' N/m', ' N  ', sim%cfg%domain%dimension == 2)
        do k = 1, size(forces, 3)
            write(line, '(a,3es13.5,a,3es13.5,a)') 'force on ' // &
                trim(sim%solids%list(k)%name) // ':', forces(:, 1, k) + forces(:, 2, k), &
                trim(unit_text) // ' (viscous part', forces(:, 2, k), ')'
            call log_info(trim(line))
        end do
    end procedure simulation_log_forces

    module procedure simulation_check_report
        type(timestep_limits_t) :: lim
        integer :: level, max_level
        integer(i8) :: counts(4), pairs, mine
        real(wp) :: bytes, base, limit_value, remaining
        character(len=256) :: line
        character(len=:), allocatable :: limiting
        max_level = int(global_max(env, int(maxval(sim%p%level(1:sim%p%n_owned), &
            mask=sim%p%n_owned > 0), i8)))
        do level = 0, max(max_level, 0)
            ! (virtual particles apart: they were counted as walls, fz43)
            counts = global_sum(env, [ &
                int(count(sim%p%kind(1:sim%p%n_owned) == KIND_FLUID .and. &
                    sim%p%level(1:sim%p%n_owned) == level), i8), &
                int(count(sim%p%kind(1:sim%p%n_owned) == KIND_WALL .and. &
                    sim%p%level(1:sim%p%n_owned) == level), i8), &
                int(count(sim%p%kind(1:sim%p%n_owned) == KIND_VIRTUAL .and. &
                    sim%p%level(1:sim%p%n_owned) == level), i8), &
                int(count(sim%p%level(1:sim%p%n_owned) == level), i8)])
            write(line, '(a,i0,a,i0,a,i0,a,i0,a)') 'check: level ', level, ': ', counts(4), &
                ' particles (', counts(1), ' fluid, ', counts(2), ' wall'
            if (counts(3) > 0) write(line, '(a,a,i0,a)') trim(line), ', ', counts(3), &
                ' virtual'
            line = trim(line) // ')'
            call log_info(trim(line))
        end do
        pairs = global_sum(env, int(sim%nl%n_pairs, i8))
        call evaluate_rates(sim, env)
        ! the memory in use after the set-up and a first evaluation of the rates, measured
        ! (the process's peak): the particle fields and the neighbour list alone, estimated
        ! before, came out 1.4-2.7 times below a run's peak (the libraries' 19 MB a rank,
        ! the halo, the cell lists and the pair loop's scratch)
        mine = peak_resident_bytes()
        if (global_max(env, merge(1_i8, 0_i8, mine < 0)) == 0) then
            bytes = global_sum(env, real(mine, wp))
            ! per particle above the libraries' share (a rank's whatever its particles)
            base = global_sum(env, real(max(startup_memory_bytes(), 0_i8), wp))
            call log_info('check: memory ' // mb_text(real(global_max(env, mine), wp)) // &
                ' on the largest rank, ' // mb_text(bytes) // ' over all ranks (' // &
                mb_text(base) // ' of it the libraries'', then ' // int_text(nint((bytes - &
                base) / max(1.0_wp, real(global_sum(env, int(sim%p%n_owned, i8)), wp)), &
                i8)) // ' bytes a particle; ' // int_text(pairs) // ' neighbour pairs), ' // &
                'measured after the set-up and a first evaluation of the rates: a run ' // &
                'without remeshing peaks 4-6 MB a rank above it (the output''s buffers)')
        else
            call log_info('check: memory not measured (the system gives no peak resident ' // &
                'set: /proc/self/status)')
        end if
        call log_remesh_memory(sim, env)
        lim = stable_timestep(sim, env)
        limit_value = lim%dt
        limiting = 'CFL'
        if (lim%viscous <= min(lim%cfl, lim%force)) limiting = 'viscous'
        if (lim%force <= min(lim%cfl, lim%viscous)) limiting = 'force'
        if (sim%cfg%numerics%fixed_dt > 0.0_wp) then
            limit_value = sim%cfg%numerics%fixed_dt
            limiting = '&numerics fixed_dt'
        end if
        write(line, '(a,es10.3,a,es10.3,a,es10.3,a,es10.3,a)') 'check: first time step ', &
            limit_value, ' s, limited by ' // limiting // ' (CFL ', lim%cfl, ', viscous ', &
            lim%viscous, ', force ', lim%force, ')'
        call log_info(trim(line))
        remaining = max(0.0_wp, sim%cfg%run%t_end - sim%time)
        ! (no count beyond an integer's range, or beyond a real's: t_end = 1e308)
        if (remaining < 1.0e15_wp * limit_value) then
            write(line, '(a,i0,a,es10.3,a)') 'check: about ', nint(remaining / limit_value, &
                i8), ' steps to t_end = ', sim%cfg%run%t_end, ' s at that step'
        else
            write(line, '(a,es11.3e3,a)') 'check: more than 1e15 steps to t_end = ', &
                sim%cfg%run%t_end, ' s at that step'
        end if
        call log_info(trim(line))
        ! max_steps (1e8 by default) would end the run first
        if (remaining >= real(sim%cfg%run%max_steps - sim%step, wp) * limit_value) then
            write(line, '(a,i0,a,es10.3,a,es10.3,a)') 'check: &run max_steps = ', &
                sim%cfg%run%max_steps, ' ends the run first, near t = ', sim%time + &
                real(sim%cfg%run%max_steps - sim%step, wp) * limit_value, &
                ' s at that step, before t_end = ', sim%cfg%run%t_end, ' s'
            call log_info(trim(line))
        end if
        ! (a refinement every 0.5 s to t_end = 1 s took 4734 steps where the check said
        ! about 1893, without a word; fz41)
        if (trim(sim%cfg%remesh%mode) == 'refine' .or. trim(sim%cfg%remesh%mode) == &
            'coarsen') call log_info("check: &remesh mode = '" // trim(sim%cfg%remesh%mode) // &
            "' changes the spacing during the run, and with it the time step and the " // &
            'particle count: the figures above hold until the first remesh')
        if (multires(sim)) call log_info('check: virtual particles by the ' // &
            trim(sim%cfg%refinement%virtual_rule) // ' rule (&refinement virtual_rule)')
        if (sim%subcycling) then
            sim%last_limits = lim
            write(line, '(a,*(i0,:,", "))') 'check: sub-cycling, steps of the finest level ' // &
                'per step of levels 0.. : ', planned_substeps(sim, limit_value)
            call log_info(trim(line))
        end if
    end procedure simulation_check_report

    module procedure simulation_log_levels
        integer(i8), allocatable :: n_real(:), n_virtual(:), became(:), left(:)
        real(wp), allocatable :: mass(:), momentum(:, :), crossed(:)
        real(wp) :: per_update, weight
        integer :: lv, n
        character(len=320) :: line
        if (.not. multires(sim)) return
        n = sim%zones%n_levels
        allocate(n_real(0:n - 1), n_virtual(0:n - 1), mass(0:n - 1), momentum(3, 0:n - 1))
        call level_totals(env, sim%p, n, n_real, n_virtual, mass, momentum)
        became = global_sum(env, sim%level_stats%became_real(0:n - 1))
        left = global_sum(env, sim%level_stats%left(0:n - 1))
        crossed = global_sum(env, [sim%level_stats%mass_in(0:n - 1), &
            sim%level_stats%mass_out(0:n - 1)])
        ! (the zones are made anew when the particles have moved a twentieth of h, not every
        ! step: the line said 'per step' for counts per update, fz34)
        per_update = 1.0_wp / real(max(sim%level_stats%updates, 1_i8), wp)
        do lv = 0, n - 1
            write(line, '(a,i0,a,i0,a,i0,a,f8.3,a,f8.3,a,es16.9,a,a,a,2es10.3,a,3es11.3)') &
                '  level ', lv, ': ', n_real(lv), ' real, ', n_virtual(lv), &
                ' virtual; per zone update ', real(became(lv + 1), wp) * per_update, &
                ' became real, ', real(left(lv + 1), wp) * per_update, ' left; real mass ', &
                mass(lv), &
                ' kg (drift ', drift_text(mass(lv), sim%first_level_mass(lv)), &
                ', in/out since last line', crossed(lv + 1), &
                crossed(n + lv + 1), '), momentum', momentum(:, lv)
            call log_info(trim(line))
        end do
        write(line, '(a,es16.9,a,a,a,i0,a,i0,a,i0)') '  all levels: real mass ', &
            sum(mass), ' kg (drift ', drift_text(sum(mass), sum(sim%first_level_mass)), &
            '); interpolation fallbacks ', &
            global_sum(env, sim%level_stats%fallbacks), ', clipped ', &
            global_sum(env, sim%level_stats%clipped), ', virtuals without sources ', &
            global_sum(env, sim%level_stats%empty)
        call log_info(trim(line))
        if (sim%cfg%refinement%conserve) then
            ! the corrections of &refinement conserve: what the conversions' imbalance was,
            ! and the mean virtual push on the real fluid against the body force on it
            write(line, '(a,es11.3,a,3es11.3,a)') '  conserve: mass put back ', &
                sim%mass_restored, ' kg; virtual push ' // trim(merge('removed', 'kept   ', &
                sim%cfg%refinement%remove_push)), sim%push_removed / &
                real(max(sim%push_evaluations, 1_i8), wp), ' N (mean'
            ! against the body force on the real fluid, when there is one (not in Couette)
            weight = norm2(sim%phys%body_force) * sim%reference_mass
            if (weight > 0.0_wp) then
                write(line(len_trim(line) + 1:), '(a,es10.3,a)') '; ', &
                    norm2(sim%push_removed) / real(max(sim%push_evaluations, 1_i8), wp) / &
                    weight, ' of the body force)'
            else
                line = trim(line) // ')'
            end if
            call log_info(trim(line))
            sim%mass_restored = 0.0_wp
            sim%push_removed = 0.0_wp
            sim%push_evaluations = 0
        end if
        sim%level_stats = level_stats_t()
    contains
        !> The relative change of a real mass from its start, or n/a for a level that started
        !> without any (a region holding no particle of its level: 0 / 0).
        function drift_text(now, start) result(text)
            real(wp), intent(in) :: now, start
            character(len=10) :: text
            if (start > 0.0_wp) then
                write(text, '(es10.3)') (now - start) / start
            else
                text = '       n/a'
            end if
        end function drift_text
    end procedure simulation_log_levels

    module procedure simulation_analytic_error
        logical :: against_steady
        real(wp) :: sums(2)
        integer(i8) :: n_fluid
        error = -1.0_wp
        if (trim(sim%ref%name) == 'none') return
        against_steady = .false.
        if (present(steady)) against_steady = steady
        sums = global_sum(env, relative_l2_error(sim%ref, sim%p, sim%time, against_steady))
        n_fluid = global_sum(env, int(count(sim%p%kind(1:sim%p%n_owned) == KIND_FLUID), i8))
        error = UNRESOLVED
        if (n_fluid > 0_i8) then
            if (.not. reference_resolved(sim%ref, sqrt(sums(2) / real(n_fluid, wp)))) return
        end if
        error = relative_l2_from_sums(sums)
    end procedure simulation_analytic_error

    module procedure simulation_write_snapshot
        character(len=:), allocatable :: path, errmsg, xdmf_path, message
        integer :: stat, k
        integer(i8) :: rows
        real(wp) :: error
        character(len=160) :: line
        call synchronise(sim, env)
        path = snapshot_filename(trim(sim%cfg%output%output_dir), trim(sim%cfg%run%case_name), &
            sim%step)
        call write_snapshot(env, sim%p, path, sim%time, sim%step, sim%cfg%domain%dimension, &
            code_version, sim%input_text, stat, errmsg, with_virtual=writes_virtual(sim), &
            dx=sim%cfg%domain%dx)
        ! (the folder is the user's key: named, since the message gives the path only)
        if (stat /= 0) call fatal_collective('output', errmsg // ' (&output output_dir)', &
            STATUS_OUTPUT_FAILED, abort=stat == SNAPSHOT_NOT_CLOSED)
        rows = global_sum(env, int(count(sim%p%kind(1:sim%p%n_owned) /= KIND_VIRTUAL .or. &
            writes_virtual(sim)), i8))
        k = index(path, '/', back=.true.)
        sim%snapshot_index = sim%snapshot_index // xdmf_index_entry(sim%time, sim%step, rows, &
            path(k + 1:))
        xdmf_path = trim(sim%cfg%output%output_dir) // '/' // trim(sim%cfg%run%case_name) // &
            '.xdmf'
        stat = 0
        message = ''
        if (env%rank == 0) call write_xdmf(xdmf_path, sim%snapshot_index, stat, message)
        if (global_max(env, int(stat, i8)) /= 0) call fatal_collective('output', &
            "cannot write '" // xdmf_path // "': " // message // &
            ' (&output output_dir; the earlier files are whole)', STATUS_OUTPUT_FAILED)
        ! (the path in a string of its own length: a fixed line cut long paths short)
        write(line, '(es12.5)') sim%time
        message = 'snapshot t = ' // trim(line) // ' s: ' // path
        if (trim(sim%ref%name) /= 'none' .and. sim%time > 0.0_wp) then
            error = simulation_analytic_error(sim, env)
            message = message // ' (L2 error vs analytic ' // &
                error_percent_text(error, 8, 4) // ')'
        end if
        call log_info(message)
    end procedure simulation_write_snapshot

    !> Snapshots hold the virtual particles of transition zones only when asked
    !> (&refinement write_virtual); checkpoints always do.
    logical function writes_virtual(sim)
        type(simulation_t), intent(in) :: sim
        writes_virtual = sim%cfg%refinement%write_virtual
    end function writes_virtual

    module procedure simulation_neighbours_per_particle
        integer(i8) :: counts(2)
        integer :: i, j, k
        real(wp) :: r2max
        counts = 0
        do i = 1, sim%nl%n_query
            r2max = sim%level_phys(sim%p%level(i))%kernel%support**2
            do k = sim%nl%start(i), sim%nl%start(i + 1) - 1
                j = sim%nl%index(k)
                if (sum((sim%p%x(:, i) - sim%p%x(:, j))**2) < r2max) counts(1) = counts(1) + 1
            end do
        end do
        counts(2) = sim%nl%n_query
        counts = global_sum(env, counts)
        mean = real(counts(1), wp) / real(max(counts(2), 1_i8), wp)
    end procedure simulation_neighbours_per_particle

    module procedure fluid_density_range
        range(1) = global_min(env, fluid_extreme(sim%p, .false.))
        range(2) = global_max(env, fluid_extreme(sim%p, .true.))
    end procedure fluid_density_range

    pure real(wp) function fluid_extreme(p, want_max)
        type(particles_t), intent(in) :: p
        logical, intent(in) :: want_max
        integer :: i
        fluid_extreme = merge(-huge(1.0_wp), huge(1.0_wp), want_max)
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_FLUID) cycle
            if (want_max) then
                fluid_extreme = max(fluid_extreme, p%rho(i))
            else
                fluid_extreme = min(fluid_extreme, p%rho(i))
            end if
        end do
    end function fluid_extreme
end submodule sph_stepper_output
