!> Particle shifting (`&numerics shifting = 'lind'`): the Fickian shift of Lind, Xu, Stansby
!> & Rogers (2012, J. Comput. Phys. 231:1499), applied once per step after the corrector:
!>   C_i      = sum_j V_j W_ij                 (particle concentration, V_j = m_j / rho_j)
!>   grad C_i = sum_j V_j grad_i W_ij
!>   dr_i     = -D grad C_i,   D = A h |v|_max dt
!> with |dr_i| capped at shifting_limit * dx, and the velocity carried to the new position by
!> the first-order Taylor term  v_i += (dr_i . grad) v_i,  grad v_i = sum_j V_j (v_j - v_i) (x)
!> grad_i W_ij, as Lind et al. do (density is not corrected: it is the particle's own
!> integrated density, and dr . grad rho is far below the density's own error here).
!> Why this form: D = A h |v|_max dt scales the shift with the distance the flow itself moves
!> a particle in a step, so the lattice is relaxed at the rate the flow disorders it and the
!> shift vanishes with the flow (a fluid at rest is never moved); the Skillen et al. (2013)
!> D = A h^2 form would re-lattice at a fixed rate regardless of the flow, and the delta-plus
!> form of Sun et al. (2017) adds a free-surface treatment these confined flows do not need.
!> Walls: the sums include the Morris wall particles, which fill the support behind every wall
!> on the fluid lattice, so the wall is part of the concentration field (no normal-component
!> removal is needed: a fluid particle pushed towards a wall sees a rising C and is pushed
!> back). Shifting is therefore accepted with wall_model = 'morris' only.
!> Only fluid particles move. Loops run over owned particles and read ghosts, whose positions
!> and velocities must be current (the driver refreshes the halo before this stage). No MPI.
module sph_shifting
    use sph_kinds, only: wp
    use sph_particles, only: particles_t, KIND_WALL, moves_with_flow
    use sph_cell_list, only: neighbour_list_t
    use sph_physics, only: physics_t
    implicit none
    private
    public :: shifting_diffusion, shift_displacements, apply_shift, shift_particles

contains

    !> Lind's diffusion coefficient D = A h |v|_max dt (m^2).
    pure real(wp) function shifting_diffusion(phys, max_speed, dt) result(diffusion)
        type(physics_t), intent(in) :: phys
        real(wp), intent(in) :: max_speed, dt
        diffusion = phys%shifting_coefficient * phys%kernel%h * max_speed * dt
    end function shifting_diffusion

    !> dr_i = -D grad C_i for owned fluid particles (zero for the others), each capped at
    !> `limit` in length (direction kept).
    subroutine shift_displacements(phys, p, nl, diffusion, limit, dr, level)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(in) :: p
        type(neighbour_list_t), intent(in) :: nl
        real(wp), intent(in) :: diffusion, limit
        real(wp), intent(out) :: dr(:, :)   !< (3, n_owned)
        integer, intent(in), optional :: level   !< only particles of this level (else dr = 0)
        integer :: i, k, j
        real(wp) :: d(3), r, grad_c(3), length, support
        support = phys%kernel%support
        do i = 1, p%n_owned
            dr(:, i) = 0.0_wp
            if (.not. moves_with_flow(p%kind(i))) cycle
            if (present(level)) then
                if (p%level(i) /= level) cycle
            end if
            grad_c = 0.0_wp
            do k = nl%start(i), nl%start(i + 1) - 1
                j = nl%index(k)
                if (.not. in_concentration(p%kind(j))) cycle
                d = p%x(:, i) - p%x(:, j)
                r = norm2(d)
                if (r <= 0.0_wp .or. r >= support) cycle
                grad_c = grad_c + p%m(j) / p%rho(j) * phys%kernel%dwdr(r) / r * d
            end do
            dr(:, i) = -diffusion * grad_c
            length = norm2(dr(:, i))
            if (length > limit) dr(:, i) = dr(:, i) * (limit / length)
        end do
    end subroutine shift_displacements

    !> Move the owned particles by dr; with correct_velocity, first carry each velocity to the
    !> new position by v_i += (dr_i . grad) v_i (all gradients from the unshifted state).
    subroutine apply_shift(phys, p, nl, dr, correct_velocity)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        real(wp), intent(in) :: dr(:, :)
        logical, intent(in) :: correct_velocity
        real(wp), allocatable :: dv(:, :)
        integer :: i, k, j, b
        real(wp) :: d(3), r, grad(3), g(3, 3), support
        support = phys%kernel%support
        allocate(dv(3, p%n_owned))
        dv = 0.0_wp
        if (correct_velocity) then
            do i = 1, p%n_owned
                if (.not. moves_with_flow(p%kind(i))) cycle
                if (all(dr(:, i) == 0.0_wp)) cycle
                g = 0.0_wp      ! g(a, b) = d v^b / d x^a
                do k = nl%start(i), nl%start(i + 1) - 1
                    j = nl%index(k)
                    if (.not. in_concentration(p%kind(j))) cycle
                    d = p%x(:, i) - p%x(:, j)
                    r = norm2(d)
                    if (r <= 0.0_wp .or. r >= support) cycle
                    grad = p%m(j) / p%rho(j) * phys%kernel%dwdr(r) / r * d
                    do b = 1, 3
                        g(:, b) = g(:, b) + (p%v(b, j) - p%v(b, i)) * grad
                    end do
                end do
                do b = 1, 3
                    dv(b, i) = dot_product(dr(:, i), g(:, b))
                end do
            end do
        end if
        do i = 1, p%n_owned
            if (.not. moves_with_flow(p%kind(i))) cycle
            p%x(:, i) = p%x(:, i) + dr(:, i)
            p%v(:, i) = p%v(:, i) + dv(:, i)
        end do
    end subroutine apply_shift

    !> One shifting pass with diffusion coefficient D, limit shifting_limit dx and the
    !> velocity correction; returns the largest shift of an owned particle.
    subroutine shift_particles(phys, p, nl, diffusion, largest, level)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        real(wp), intent(in) :: diffusion
        real(wp), intent(out), optional :: largest
        integer, intent(in), optional :: level   !< shift only the particles of this level
        real(wp), allocatable :: dr(:, :)
        integer :: i
        allocate(dr(3, p%n_owned))
        call shift_displacements(phys, p, nl, diffusion, phys%shifting_limit * phys%dx, dr, &
            level)
        call apply_shift(phys, p, nl, dr, .true.)
        if (present(largest)) then
            largest = 0.0_wp
            do i = 1, p%n_owned
                largest = max(largest, norm2(dr(:, i)))
            end do
        end if
    end subroutine shift_particles

    !> Fluid and Morris wall particles make up the concentration field (mirrors do not occur:
    !> shifting is accepted with Morris walls only).
    pure logical function in_concentration(kind_j)
        integer, intent(in) :: kind_j
        in_concentration = moves_with_flow(kind_j) .or. kind_j == KIND_WALL
    end function in_concentration
end module sph_shifting
