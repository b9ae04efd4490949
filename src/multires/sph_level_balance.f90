!> The real fluid's totals across resolution levels (issue 11; multiresolution.md,
!> "Conservation"). The levels exchange mass and momentum only through their virtual
!> particles, which are made anew from the other level at every transition update, so
!> neither total is kept by construction:
!>  - momentum: a real particle next to the interface feels its level's virtual particles,
!>    whose reaction goes to particles that are then discarded. Each level's push on its own
!>    is the interface stress and is physical; their sum over the levels would vanish if the
!>    two levels' virtual particles stood for the same fluid, and it does not (on the
!>    cylinder with a fine ring it reached 14 % of the body force on the real fluid,
!>    retarding it). The sum is measured by the balance of the real fluid of each level,
!>      V = sum m dv/dt - F sum m + D,
!>    F the body force and D the force the level's real fluid exerts on the solids (every
!>    pair among real particles, walls and ghosts is antisymmetric and cancels or is in D),
!>    and removed as one acceleration of the real particles that have a virtual partner
!>    within the kernel support: where it arises;
!>  - mass: a conversion turns a virtual particle real with the mass its construction gave
!>    it, which need not match what left the other level (a coarse particle's children
!>    cross one by one, the fine particles that stand in for a coarse one are picked by
!>    parity), so the total wandered by a few per cent on the cylinder. After each update the
!>    masses of the real fluid and the walls are scaled by one factor back to the reference
!>    total: at a fresh start the fluid's mass as the uniform lattice of level 0 holds it
!>    (rho0 times the fluid volume), to which the set-up's masses are scaled too (the
!>    levels' lattices both count the cells the interfaces cut, +1.4 % on the cylinder).
!> The driver (sph_stepper) sums over the ranks; nothing here calls MPI.
module sph_level_balance
    use sph_kinds, only: wp
    use sph_particles, only: particles_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL
    use sph_cell_list, only: neighbour_list_t
    use sph_accurate_sums, only: accurate_add
    implicit none
    private
    public :: PUSH_SUMS, mark_near_virtual, level_push_sums, remove_virtual_push
    public :: real_fluid_mass, scale_masses

    !> level_push_sums' values per level: sum m dv/dt (3), sum m, sum m of the particles
    !> next to a virtual one
    integer, parameter :: PUSH_SUMS = 5

contains

    !> near_virtual(i): owned real fluid particle i has a virtual partner closer than
    !> support(its level) now. With `among`, only the particles it marks are looked at (the
    !> caller marks, at each new neighbour list, those within the support plus the list's
    !> skin: every particle that can come that close before the next list). The mark must
    !> be of the current positions, not of the list's: a set kept from list to list changed
    !> with the rebuilds that output and restarts make, and a multi-resolution run stopped
    !> and continued then departed from the uninterrupted one by 5e-5 of its peak speed.
    subroutine mark_near_virtual(p, nl, support, near_virtual, among)
        type(particles_t), intent(in) :: p
        type(neighbour_list_t), intent(in) :: nl
        real(wp), intent(in) :: support(0:)
        logical, intent(out) :: near_virtual(:)
        logical, intent(in), optional :: among(:)
        integer :: i, k, j
        real(wp) :: d(3), support2
        do i = 1, p%n_owned
            near_virtual(i) = .false.
            if (p%kind(i) /= KIND_FLUID) cycle
            if (present(among)) then
                if (.not. among(i)) cycle
            end if
            support2 = support(p%level(i))**2
            do k = nl%start(i), nl%start(i + 1) - 1
                j = nl%index(k)
                if (p%kind(j) /= KIND_VIRTUAL) cycle
                d = p%x(:, i) - p%x(:, j)
                if (d(1)**2 + d(2)**2 + d(3)**2 >= support2) cycle
                near_virtual(i) = .true.
                exit
            end do
        end do
    end subroutine mark_near_virtual

    !> Over the owned real fluid particles of `level`: sums(1:3) = sum m dv/dt, sums(4) =
    !> sum m, sums(5) = sum m of those marked near_virtual (mark_near_virtual).
    subroutine level_push_sums(p, level, near_virtual, sums)
        type(particles_t), intent(in) :: p
        integer, intent(in) :: level
        logical, intent(in) :: near_virtual(:)
        real(wp), intent(out) :: sums(PUSH_SUMS)
        integer :: i
        sums = 0.0_wp
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_FLUID .or. p%level(i) /= level) cycle
            sums(1) = sums(1) + p%m(i) * p%dvdt(1, i)
            sums(2) = sums(2) + p%m(i) * p%dvdt(2, i)
            sums(3) = sums(3) + p%m(i) * p%dvdt(3, i)
            sums(4) = sums(4) + p%m(i)
            if (near_virtual(i)) sums(5) = sums(5) + p%m(i)
        end do
    end subroutine level_push_sums

    !> dv/dt -= accel for the owned real fluid particles of `level` next to a virtual one
    !> (near_virtual, as mark_near_virtual left it).
    subroutine remove_virtual_push(p, level, near_virtual, accel)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: level
        logical, intent(in) :: near_virtual(:)
        real(wp), intent(in) :: accel(3)
        integer :: i
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_FLUID .or. p%level(i) /= level) cycle
            if (.not. near_virtual(i)) cycle
            p%dvdt(:, i) = p%dvdt(:, i) - accel
        end do
    end subroutine remove_virtual_push

    !> Mass of the owned real fluid particles, every level, compensated: the levels' mass
    !> factor is its ratio to a reference, and with a plain sum the factor's rounding
    !> followed the partition (4 ranks against 1: masses 1.5e-14 apart after 200 steps, a
    !> wall's force 1.6e-10 of its peak; fz37).
    pure real(wp) function real_fluid_mass(p) result(mass)
        type(particles_t), intent(in) :: p
        real(wp) :: lost
        integer :: i
        mass = 0.0_wp
        lost = 0.0_wp
        do i = 1, p%n_owned
            if (p%kind(i) == KIND_FLUID) call accurate_add(mass, lost, p%m(i))
        end do
        mass = mass + lost
    end function real_fluid_mass

    !> m *= factor for the owned real fluid and wall particles: the levels' unit of mass.
    !> Densities are kept (the rescale spreads what the conversions gained or lost over the
    !> fluid's volume). The walls go with the fluid so that a wall particle pushes back as
    !> hard as the fluid next to it: with the fluid alone rescaled, the cylinder's fluid was
    !> 3.5 % heavier than its wall particles by 5000 s and a particle entered the cylinder.
    subroutine scale_masses(p, factor)
        type(particles_t), intent(inout) :: p
        real(wp), intent(in) :: factor
        integer :: i
        do i = 1, p%n_owned
            if (p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_WALL) p%m(i) = p%m(i) * factor
        end do
    end subroutine scale_masses
end module sph_level_balance
