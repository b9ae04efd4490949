!> Predictor-corrector (midpoint) stepping, thesis section 4.2:
!>   predictor  q* = q^n + dt/2 F(q^n),    x* = x^n + dt/2 v^n
!>   corrector  q^{n+1} = q^n + dt F(q*),  x^{n+1} = x^n + dt v*
!> Both stages are `advance` from the saved start-of-step state with the current rates and
!> velocity; it is second order in dt. Walls stay in place; their density follows the
!> continuity equation when it is integrated.
!>
!> Velocity Verlet (kick-drift-kick, as LAMMPS' fix sph), one rate evaluation per step, with
!> the rates F(q^n) kept from the previous step:
!>   verlet_drift  v_half = v^n + dt/2 a^n (rho, e likewise), x^{n+1} = x^n + dt v_half,
!>                 and the estimate v = v_half + dt/2 a^n (rho, e likewise) the rates of the
!>                 new positions are evaluated with
!>   verlet_kick   v^{n+1} = v_half + dt/2 a^{n+1} (rho, e likewise)
!> The half-step values are kept in v_old, rho_old, e_old; x_old holds x^n where it is read
!> (a step that shifts the particles; the sub-cycled levels below).
!>
!> Sub-cycled velocity Verlet (multi-resolution runs, &refinement max_subcycles): level L
!> takes one Verlet step of span H_L = k_L dt over k_L steps dt of the finest level. At its
!> start the half kick with H_L / 2; at every fine step every particle drifts, the state of
!> a level in the middle of its step being the start state carried on with the start
!> rates (x = x^n + t v_half, v = v^n + t a^n, t the time since the level's step began);
!> at its end the rates of the levels that end are evaluated and they get their second half
!> kick. A step cut short (an output time) is closed with half kicks of the time it
!> actually took. With every k_L = 1 this is velocity Verlet, bit for bit.
module sph_integrator
    use sph_kinds, only: wp
    use sph_particles, only: particles_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL
    implicit none
    private
    public :: save_step_start, advance, max_step_displacement
    public :: verlet_drift, verlet_kick, stage_displacement_bound
    public :: verlet_drift_levels, verlet_close_levels, verlet_kick_levels

contains

    !> Keep the step-start state (x, v, rho, e) of the owned particles for the stages.
    subroutine save_step_start(p)
        type(particles_t), intent(inout) :: p
        integer :: n
        n = p%n_owned
        p%x_old(:, 1:n) = p%x(:, 1:n)
        p%v_old(:, 1:n) = p%v(:, 1:n)
        p%rho_old(1:n) = p%rho(1:n)
        p%e_old(1:n) = p%e(1:n)
    end subroutine save_step_start

    !> q = q_old + dt_stage * rate for owned particles; density only when it is integrated.
    !> With `transport` (the transport-velocity formulation, Adami, Hu & Adams 2013) the
    !> particles move with the transport velocity v + dv_transport of the current state, and
    !> the new state's is v + dt_stage a_b (a_b = dvdt_background, the background pressure's
    !> acceleration): over a step the particles then move by dt v* + dt^2/2 a_b(q^n), as in
    !> Adami's kick-drift-kick scheme.
    subroutine advance(p, dt_stage, integrate_density, transport, integrate_energy)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt_stage
        logical, intent(in) :: integrate_density
        logical, intent(in), optional :: transport
        !> the energy too (default); without the energy equation its rates are 0 and the
        !> pass over it can go
        logical, intent(in), optional :: integrate_energy
        integer :: n
        if (present(transport)) then
            if (transport) then
                call advance_transport(p, dt_stage)
                return
            end if
        end if
        n = p%n_owned
        ! owned particles are fluid, virtual or wall: every density integrated
        if (integrate_density) p%rho(1:n) = p%rho_old(1:n) + dt_stage * p%drhodt(1:n)
        ! the positions first: they move with the velocity of the state the rates came from
        call from_start(n, dt_stage, p%kind, p%x_old, p%v, p%x)
        call from_start(n, dt_stage, p%kind, p%v_old, p%dvdt, p%v)
        if (wants_energy(integrate_energy)) &
            call from_start_scalar(n, dt_stage, p%kind, p%e_old, p%dedt, p%e)
    end subroutine advance

    !> The energy is integrated unless integrate_energy says otherwise.
    pure logical function wants_energy(integrate_energy)
        logical, intent(in), optional :: integrate_energy
        wants_energy = .true.
        if (present(integrate_energy)) wants_energy = integrate_energy
    end function wants_energy

    !> advance for the transport-velocity formulation (density from summation: not integrated).
    subroutine advance_transport(p, dt_stage)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt_stage
        integer :: i
        do i = 1, p%n_owned
            select case (p%kind(i))
            case (KIND_FLUID, KIND_VIRTUAL)
                p%x(:, i) = p%x_old(:, i) + dt_stage * (p%v(:, i) + p%dv_transport(:, i))
                p%v(:, i) = p%v_old(:, i) + dt_stage * p%dvdt(:, i)
                p%dv_transport(:, i) = dt_stage * p%dvdt_background(:, i)
                p%e(i) = p%e_old(i) + dt_stage * p%dedt(i)
            end select
        end do
    end subroutine advance_transport

    !> The first half kick and the drift of velocity Verlet (module header), for owned
    !> particles with the kept rates; then the state estimate for the rate evaluation.
    !> Walls stay in place; their density follows the continuity equation when it is
    !> integrated. One resolution level (every particle on level 0): the levels' drift with
    !> one level stepping at dt, which is this step bit for bit.
    subroutine verlet_drift(p, dt, integrate_density, moved, keep_start, integrate_energy)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt
        logical, intent(in) :: integrate_density
        logical, intent(in), optional :: integrate_energy  !< as advance's
        !> the largest distance an owned particle moved (dt |v_half|)
        real(wp), intent(out), optional :: moved
        !> also keep x^n in x_old (a step that shifts the particles measures its displacement
        !> from there); otherwise x_old is left as it was
        logical, intent(in), optional :: keep_start
        real(wp) :: h2, moved2, rh
        logical :: keep
        integer :: i, n
        keep = .false.
        if (present(keep_start)) keep = keep_start
        ! verlet_drift_levels with one level, in a loop without branches that the compiler
        ! vectorises (the general loop was 8 % of a channel step); the same arithmetic, so
        ! the same values bit for bit: the levels' t = 0 + dt and t - dt/2 are exact
        h2 = 0.5_wp * dt
        n = p%n_owned
        if (keep) p%x_old(:, 1:n) = p%x(:, 1:n)
        if (integrate_density) then
            do i = 1, n
                rh = p%rho(i) + h2 * p%drhodt(i)
                p%rho_old(i) = rh
                p%rho(i) = rh + h2 * p%drhodt(i)
            end do
        else
            p%rho_old(1:n) = p%rho(1:n)
        end if
        call drift_one_level(n, dt, p%kind, p%x, p%v, p%dvdt, p%v_old, moved2)
        if (wants_energy(integrate_energy)) &
            call drift_energy(n, dt, p%kind, p%e, p%dedt, p%e_old)
        if (present(moved)) moved = dt * sqrt(moved2)
    end subroutine verlet_drift

    !> verlet_drift's update of positions and velocities (explicit shapes: with the leading
    !> extent 3 known the compiler vectorises the loop); moved2: the largest |v_half|^2 of a
    !> moving particle.
    subroutine drift_one_level(n, dt, kind, x, v, dvdt, v_old, moved2)
        integer, intent(in) :: n, kind(n)
        real(wp), intent(in) :: dt, dvdt(3, n)
        real(wp), intent(inout) :: x(3, n), v(3, n)
        real(wp), intent(out) :: v_old(3, n), moved2
        real(wp) :: vh(3), f, ht, hv
        integer :: i
        moved2 = 0.0_wp
        do i = 1, n
            ! owned particles are fluid, virtual or wall: all integrated, walls do not move.
            ! A factor 0 or 1 rather than a choice (merge, if): the compiler turns a choice
            ! into masked stores, which it cannot vectorise here; dt * 1 is dt exactly, and
            ! a wall's v + 0 dv/dt is v
            f = merge(1.0_wp, 0.0_wp, kind(i) /= KIND_WALL)
            ht = (0.5_wp * dt) * f
            hv = dt * f
            vh(1) = v(1, i) + ht * dvdt(1, i)
            vh(2) = v(2, i) + ht * dvdt(2, i)
            vh(3) = v(3, i) + ht * dvdt(3, i)
            v_old(1, i) = vh(1)
            v_old(2, i) = vh(2)
            v_old(3, i) = vh(3)
            x(1, i) = x(1, i) + hv * vh(1)
            x(2, i) = x(2, i) + hv * vh(2)
            x(3, i) = x(3, i) + hv * vh(3)
            v(1, i) = vh(1) + ht * dvdt(1, i)
            v(2, i) = vh(2) + ht * dvdt(2, i)
            v(3, i) = vh(3) + ht * dvdt(3, i)
            moved2 = max(moved2, f * (vh(1)**2 + vh(2)**2 + vh(3)**2))
        end do
    end subroutine drift_one_level

    !> drift_one_level's energies: the half kick into e_old and the estimate e, walls' kept
    !> (a loop of its own: without the energy equation the pass goes, 1.5 % of a step).
    subroutine drift_energy(n, dt, kind, e, dedt, e_old)
        integer, intent(in) :: n, kind(n)
        real(wp), intent(in) :: dt, dedt(n)
        real(wp), intent(inout) :: e(n)
        real(wp), intent(out) :: e_old(n)
        real(wp) :: eh, ht
        integer :: i
        do i = 1, n
            ht = (0.5_wp * dt) * merge(1.0_wp, 0.0_wp, kind(i) /= KIND_WALL)
            eh = e(i) + ht * dedt(i)
            e_old(i) = eh
            e(i) = eh + ht * dedt(i)
        end do
    end subroutine drift_energy

    !> The second half kick of velocity Verlet with the rates of the new positions (one
    !> resolution level, as verlet_drift). maxima: the largest speed and acceleration
    !> magnitude among the owned fluid and virtual particles after the kick, as
    !> sph_rates' local_motion_maxima finds them without the transport velocity (the next
    !> step's limits, found here while the values are at hand: a pass over the particles
    !> less).
    subroutine verlet_kick(p, dt, integrate_density, maxima, integrate_energy)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt
        logical, intent(in) :: integrate_density
        real(wp), intent(out), optional :: maxima(2)
        logical, intent(in), optional :: integrate_energy  !< as advance's
        real(wp) :: h2, speed2, accel2
        integer :: n
        ! verlet_kick_levels with one level, vectorised as verlet_drift (the same values)
        h2 = 0.5_wp * dt
        n = p%n_owned
        if (integrate_density) p%rho(1:n) = p%rho_old(1:n) + h2 * p%drhodt(1:n)
        call kick_one_level(n, h2, p%kind, p%v_old, p%dvdt, p%v, speed2, accel2)
        ! (e_old + h2 dedt) f + e (1 - f), as the velocities'
        if (wants_energy(integrate_energy)) &
            call from_start_scalar(n, h2, p%kind, p%e_old, p%dedt, p%e)
        if (present(maxima)) maxima = sqrt([speed2, accel2])
    end subroutine verlet_kick

    !> verlet_kick's update of velocities (explicit shapes, as drift_one_level), with the
    !> largest |v|^2 and |dv/dt|^2 of the fluid and virtual particles.
    subroutine kick_one_level(n, h2, kind, v_old, dvdt, v, speed2, accel2)
        integer, intent(in) :: n, kind(n)
        real(wp), intent(in) :: h2, v_old(3, n), dvdt(3, n)
        real(wp), intent(inout) :: v(3, n)
        real(wp), intent(out) :: speed2, accel2
        real(wp) :: f, g, c
        integer :: i
        speed2 = 0.0_wp
        accel2 = 0.0_wp
        do i = 1, n
            ! as from_start: f 1 for the moving particles, 0 for walls; c 1 for those the
            ! maxima count (fluid, virtual: every owned particle but walls)
            f = merge(1.0_wp, 0.0_wp, kind(i) /= KIND_WALL)
            g = 1.0_wp - f
            c = merge(1.0_wp, 0.0_wp, kind(i) == KIND_FLUID .or. kind(i) == KIND_VIRTUAL)
            v(1, i) = (v_old(1, i) + h2 * dvdt(1, i)) * f + v(1, i) * g
            v(2, i) = (v_old(2, i) + h2 * dvdt(2, i)) * f + v(2, i) * g
            v(3, i) = (v_old(3, i) + h2 * dvdt(3, i)) * f + v(3, i) * g
            speed2 = max(speed2, c * (v(1, i)**2 + v(2, i)**2 + v(3, i)**2))
            accel2 = max(accel2, c * (dvdt(1, i)**2 + dvdt(2, i)**2 + dvdt(3, i)**2))
        end do
    end subroutine kick_one_level

    !> q = q_old + s rate for the moving particles among 1..n (fluid, virtual), a wall's q
    !> kept: advance's stages (x, v) and verlet_kick's half kick (v). Explicit shapes, as
    !> drift_one_level: with the leading extent known the compiler vectorises the loop, where
    !> the per-particle choice this replaces was 9 % of a predictor-corrector channel step.
    !> q_new f + q (1 - f) with f 0 or 1 is one or the other exactly (a choice would be
    !> masked stores, which gfortran does not vectorise here).
    subroutine from_start(n, s, kind, q_old, rate, q)
        integer, intent(in) :: n, kind(n)
        real(wp), intent(in) :: s, q_old(3, n), rate(3, n)
        real(wp), intent(inout) :: q(3, n)
        real(wp) :: f, g
        integer :: i
        do i = 1, n
            f = merge(1.0_wp, 0.0_wp, kind(i) /= KIND_WALL)
            g = 1.0_wp - f
            q(1, i) = (q_old(1, i) + s * rate(1, i)) * f + q(1, i) * g
            q(2, i) = (q_old(2, i) + s * rate(2, i)) * f + q(2, i) * g
            q(3, i) = (q_old(3, i) + s * rate(3, i)) * f + q(3, i) * g
        end do
    end subroutine from_start

    !> from_start for one value a particle (the energy; verlet_kick's too).
    subroutine from_start_scalar(n, s, kind, q_old, rate, q)
        integer, intent(in) :: n, kind(n)
        real(wp), intent(in) :: s, q_old(n), rate(n)
        real(wp), intent(inout) :: q(n)
        real(wp) :: f
        integer :: i
        do i = 1, n
            f = merge(1.0_wp, 0.0_wp, kind(i) /= KIND_WALL)
            q(i) = (q_old(i) + s * rate(i)) * f + q(i) * (1.0_wp - f)
        end do
    end subroutine from_start_scalar

    !> The fine step dt of sub-cycled Verlet (module header) for owned particles: the levels
    !> with `starts` begin a step of span(L) (x_old = x^n; the half kick into v_old, rho_old,
    !> e_old), then every level drifts to elapsed(L) + dt since its step began, and elapsed
    !> advances. moved: the largest distance an owned particle moved in this fine step.
    subroutine verlet_drift_levels(p, dt, starts, span, elapsed, integrate_density, moved)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt
        logical, intent(in) :: starts(0:)
        real(wp), intent(in) :: span(0:)
        real(wp), intent(inout) :: elapsed(0:)
        logical, intent(in) :: integrate_density
        real(wp), intent(out) :: moved
        ! per level: the half kick, the time since the step began and since its middle
        real(wp) :: half(0:size(span) - 1), t(0:size(span) - 1), since_half(0:size(span) - 1)
        real(wp) :: moved2
        half = 0.5_wp * span
        t = elapsed + dt
        since_half = t - half
        call drift_levels(p%n_owned, size(span), p%kind, p%level, starts, half, t, &
            since_half, integrate_density, p%x, p%v, p%dvdt, p%x_old, p%v_old, p%rho, &
            p%rho_old, p%drhodt, p%e, p%e_old, p%dedt, moved2)
        moved = dt * sqrt(moved2)
        elapsed = t
    end subroutine verlet_drift_levels

    !> verlet_drift_levels' update of every owned particle (explicit shapes, choices as
    !> merges of values: a loop the compiler vectorises; with a branch per particle it ran
    !> 2.6 times as long per particle as verlet_drift's, a tenth of a sub-cycled
    !> multi-resolution step). The values are those of the branches bit for bit: a merge
    !> picks one of two computed values. A particle whose level starts its step keeps its
    !> start (x, and the half kick of v, rho and e) in the _old fields; walls keep x, v and e.
    subroutine drift_levels(n, n_levels, kind, level, starts, half, t, since_half, &
            integrate_density, x, v, dvdt, x_old, v_old, rho, rho_old, drhodt, e, e_old, dedt, &
            moved2)
        integer, intent(in) :: n, n_levels, kind(n), level(n)
        logical, intent(in) :: starts(0:n_levels - 1), integrate_density
        real(wp), intent(in) :: half(0:n_levels - 1), t(0:n_levels - 1), &
            since_half(0:n_levels - 1), dvdt(3, n), drhodt(n), dedt(n)
        real(wp), intent(inout) :: x(3, n), v(3, n), x_old(3, n), v_old(3, n), rho(n), &
            rho_old(n), e(n), e_old(n)
        real(wp), intent(out) :: moved2
        real(wp) :: hf, tl, sh, vo(3), eo, ro
        logical :: st, active, moving
        integer :: i, lv
        moved2 = 0.0_wp
        do i = 1, n
            active = integrated(kind(i))
            moving = active .and. kind(i) /= KIND_WALL
            lv = level(i)
            st = starts(lv) .and. active
            hf = half(lv)
            tl = t(lv)
            sh = since_half(lv)
            x_old(1, i) = merge(x(1, i), x_old(1, i), st)
            x_old(2, i) = merge(x(2, i), x_old(2, i), st)
            x_old(3, i) = merge(x(3, i), x_old(3, i), st)
            if (integrate_density) then
                ro = merge(rho(i) + hf * drhodt(i), rho_old(i), st)
            else
                ro = merge(rho(i), rho_old(i), st)
            end if
            rho_old(i) = ro
            if (integrate_density) rho(i) = merge(ro + sh * drhodt(i), rho(i), active)
            vo(1) = merge(merge(v(1, i) + hf * dvdt(1, i), v(1, i), moving), v_old(1, i), st)
            vo(2) = merge(merge(v(2, i) + hf * dvdt(2, i), v(2, i), moving), v_old(2, i), st)
            vo(3) = merge(merge(v(3, i) + hf * dvdt(3, i), v(3, i), moving), v_old(3, i), st)
            eo = merge(merge(e(i) + hf * dedt(i), e(i), moving), e_old(i), st)
            v_old(1, i) = vo(1)
            v_old(2, i) = vo(2)
            v_old(3, i) = vo(3)
            e_old(i) = eo
            x(1, i) = merge(x_old(1, i) + tl * vo(1), x(1, i), moving)
            x(2, i) = merge(x_old(2, i) + tl * vo(2), x(2, i), moving)
            x(3, i) = merge(x_old(3, i) + tl * vo(3), x(3, i), moving)
            v(1, i) = merge(vo(1) + sh * dvdt(1, i), v(1, i), moving)
            v(2, i) = merge(vo(2) + sh * dvdt(2, i), v(2, i), moving)
            v(3, i) = merge(vo(3) + sh * dvdt(3, i), v(3, i), moving)
            e(i) = merge(eo + sh * dedt(i), e(i), moving)
            moved2 = max(moved2, merge(vo(1)**2 + vo(2)**2 + vo(3)**2, 0.0_wp, moving))
        end do
    end subroutine drift_levels

    !> Before the rates of the levels that `ends` are evaluated: a level whose step took
    !> elapsed(L) instead of span(L) has its first half kick made elapsed(L) / 2 long, so
    !> that both half kicks are as long as the step was (its positions keep the drift they
    !> had, a difference of (span - elapsed) elapsed / 2 times the acceleration).
    subroutine verlet_close_levels(p, ends, span, elapsed, integrate_density)
        type(particles_t), intent(inout) :: p
        logical, intent(in) :: ends(0:)
        real(wp), intent(in) :: span(0:), elapsed(0:)
        logical, intent(in) :: integrate_density
        real(wp) :: short
        integer :: i, lv
        if (.not. any(ends .and. elapsed /= span)) return
        do i = 1, p%n_owned
            if (.not. integrated(p%kind(i))) cycle
            lv = p%level(i)
            if (.not. ends(lv) .or. elapsed(lv) == span(lv)) cycle
            short = 0.5_wp * (elapsed(lv) - span(lv))
            if (integrate_density) p%rho_old(i) = p%rho_old(i) + short * p%drhodt(i)
            if (p%kind(i) == KIND_WALL) cycle
            p%v_old(:, i) = p%v_old(:, i) + short * p%dvdt(:, i)
            p%e_old(i) = p%e_old(i) + short * p%dedt(i)
        end do
    end subroutine verlet_close_levels

    !> The second half kick, elapsed(L) / 2 long, of the levels that `ends`, with the rates
    !> just evaluated at their new positions.
    subroutine verlet_kick_levels(p, ends, elapsed, integrate_density)
        type(particles_t), intent(inout) :: p
        logical, intent(in) :: ends(0:)
        real(wp), intent(in) :: elapsed(0:)
        logical, intent(in) :: integrate_density
        real(wp) :: half
        integer :: i, lv
        do i = 1, p%n_owned
            if (.not. integrated(p%kind(i))) cycle
            lv = p%level(i)
            if (.not. ends(lv)) cycle
            half = 0.5_wp * elapsed(lv)
            if (integrate_density) p%rho(i) = p%rho_old(i) + half * p%drhodt(i)
            if (p%kind(i) == KIND_WALL) cycle
            p%v(1, i) = p%v_old(1, i) + half * p%dvdt(1, i)
            p%v(2, i) = p%v_old(2, i) + half * p%dvdt(2, i)
            p%v(3, i) = p%v_old(3, i) + half * p%dvdt(3, i)
            p%e(i) = p%e_old(i) + half * p%dedt(i)
        end do
    end subroutine verlet_kick_levels

    !> How far a particle can move before the rates of a step are evaluated, from the
    !> largest speed and acceleration of the step start: the predictor's half step
    !> (vmax + amax dt/2) dt/2, or Verlet's full-step drift dt (vmax + amax dt/2). The
    !> stepper keeps its neighbour list only while this cannot use up the skin.
    pure real(wp) function stage_displacement_bound(max_speed, max_accel, dt, verlet) &
            result(bound)
        real(wp), intent(in) :: max_speed, max_accel, dt
        logical, intent(in) :: verlet
        bound = (max_speed + 0.5_wp * dt * max_accel) * 0.5_wp * dt
        if (verlet) bound = 2.0_wp * bound
    end function stage_displacement_bound

    !> Kinds the Verlet stages update: fluid and virtual particles move, walls only have their
    !> density integrated.
    pure logical function integrated(kind)
        integer, intent(in) :: kind
        integrated = kind == KIND_FLUID .or. kind == KIND_VIRTUAL .or. kind == KIND_WALL
    end function integrated

    !> Largest distance an owned particle has moved since save_step_start.
    pure real(wp) function max_step_displacement(p) result(largest)
        type(particles_t), intent(in) :: p
        largest = sqrt(largest_square_move(p%n_owned, p%x, p%x_old))
    end function max_step_displacement

    !> The largest |x - x_old|^2 over 1..n (explicit shapes: a loop the compiler vectorises;
    !> a norm2 per particle, then the largest, was 3 % of a predictor-corrector step).
    pure real(wp) function largest_square_move(n, x, x_old) result(largest)
        integer, intent(in) :: n
        real(wp), intent(in) :: x(3, n), x_old(3, n)
        integer :: i
        largest = 0.0_wp
        do i = 1, n
            largest = max(largest, (x(1, i) - x_old(1, i))**2 + (x(2, i) - x_old(2, i))**2 + &
                (x(3, i) - x_old(3, i))**2)
        end do
    end function largest_square_move
end module sph_integrator
