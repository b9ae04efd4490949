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
!> The half-step values are kept in v_old, rho_old, e_old; x_old holds x^n.
module sph_integrator
    use sph_kinds, only: wp
    use sph_particles, only: particles_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL
    implicit none
    private
    public :: save_step_start, advance, max_step_displacement
    public :: verlet_drift, verlet_kick, stage_displacement_bound

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
    subroutine advance(p, dt_stage, integrate_density, transport)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt_stage
        logical, intent(in) :: integrate_density
        logical, intent(in), optional :: transport
        integer :: i
        if (present(transport)) then
            if (transport) then
                call advance_transport(p, dt_stage)
                return
            end if
        end if
        do i = 1, p%n_owned
            select case (p%kind(i))
            case (KIND_FLUID, KIND_VIRTUAL)
                p%x(:, i) = p%x_old(:, i) + dt_stage * p%v(:, i)
                p%v(:, i) = p%v_old(:, i) + dt_stage * p%dvdt(:, i)
                if (integrate_density) p%rho(i) = p%rho_old(i) + dt_stage * p%drhodt(i)
                p%e(i) = p%e_old(i) + dt_stage * p%dedt(i)
            case (KIND_WALL)
                if (integrate_density) p%rho(i) = p%rho_old(i) + dt_stage * p%drhodt(i)
            end select
        end do
    end subroutine advance

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
    !> integrated.
    subroutine verlet_drift(p, dt, integrate_density)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt
        logical, intent(in) :: integrate_density
        real(wp) :: half
        integer :: i
        half = 0.5_wp * dt
        do i = 1, p%n_owned
            p%x_old(:, i) = p%x(:, i)
            p%v_old(:, i) = p%v(:, i)
            p%rho_old(i) = p%rho(i)
            p%e_old(i) = p%e(i)
            if (.not. integrated(p%kind(i))) cycle
            ! walls stay in place; only their density follows the continuity equation
            if (integrate_density) then
                p%rho_old(i) = p%rho(i) + half * p%drhodt(i)
                p%rho(i) = p%rho_old(i) + half * p%drhodt(i)
            end if
            if (p%kind(i) == KIND_WALL) cycle
            p%v_old(:, i) = p%v(:, i) + half * p%dvdt(:, i)
            p%x(:, i) = p%x(:, i) + dt * p%v_old(:, i)
            p%v(:, i) = p%v_old(:, i) + half * p%dvdt(:, i)
            p%e_old(i) = p%e(i) + half * p%dedt(i)
            p%e(i) = p%e_old(i) + half * p%dedt(i)
        end do
    end subroutine verlet_drift

    !> The second half kick of velocity Verlet with the rates of the new positions.
    subroutine verlet_kick(p, dt, integrate_density)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: dt
        logical, intent(in) :: integrate_density
        real(wp) :: half
        integer :: i
        half = 0.5_wp * dt
        do i = 1, p%n_owned
            if (.not. integrated(p%kind(i))) cycle
            if (integrate_density) p%rho(i) = p%rho_old(i) + half * p%drhodt(i)
            if (p%kind(i) == KIND_WALL) cycle
            p%v(:, i) = p%v_old(:, i) + half * p%dvdt(:, i)
            p%e(i) = p%e_old(i) + half * p%dedt(i)
        end do
    end subroutine verlet_kick

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
        integer :: i
        largest = 0.0_wp
        do i = 1, p%n_owned
            largest = max(largest, norm2(p%x(:, i) - p%x_old(:, i)))
        end do
    end function max_step_displacement
end module sph_integrator
