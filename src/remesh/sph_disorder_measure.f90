!> The disorder measure that can trigger a same-level remesh during a run (&remesh
!> disorder_threshold): the coefficient of variation (std / mean) of the fluid particles'
!> nearest-fluid-neighbour distances. A lattice has 0; a developed channel flow stays near
!> 0.005 (its rows shear but keep their spacing); Morris' cylinder flow, whose particles
!> gather in pairs, reaches 0.1 at 500 s and 0.2-0.3 later (doc/validation.md). Serial, no
!> MPI: each rank sums over its owned fluid particles (neighbours through the halo), the
!> caller adds the sums over the ranks.
module sph_disorder_measure
    use sph_kinds, only: wp
    use sph_particles, only: particles_t, KIND_FLUID
    use sph_cell_list, only: neighbour_list_t
    implicit none
    private
    public :: nearest_distance_sums, disorder_from_sums

contains

    !> sums = (count, sum d, sum d^2) of the nearest fluid-neighbour distance d of the owned
    !> fluid particles that have a fluid neighbour in the list nl (built on p).
    pure function nearest_distance_sums(p, nl) result(sums)
        type(particles_t), intent(in) :: p
        type(neighbour_list_t), intent(in) :: nl
        real(wp) :: sums(3), d2, best, dd(3)
        integer :: i, k, j
        sums = 0.0_wp
        do i = 1, min(p%n_owned, nl%n_query)
            if (p%kind(i) /= KIND_FLUID) cycle
            best = huge(1.0_wp)
            do k = nl%start(i), nl%start(i + 1) - 1
                j = nl%index(k)
                if (j == i .or. p%kind(j) /= KIND_FLUID) cycle
                dd = p%x(:, j) - p%x(:, i)
                dd(p%dim + 1:) = 0.0_wp
                d2 = sum(dd * dd)
                best = min(best, d2)
            end do
            if (best >= huge(1.0_wp)) cycle
            sums = sums + [1.0_wp, sqrt(best), best]
        end do
    end function nearest_distance_sums

    !> std / mean of the distances from the (global) sums; 0 when there are none.
    pure real(wp) function disorder_from_sums(sums) result(cov)
        real(wp), intent(in) :: sums(3)
        real(wp) :: mean
        cov = 0.0_wp
        if (sums(1) < 1.0_wp) return
        mean = sums(2) / sums(1)
        if (mean <= 0.0_wp) return
        cov = sqrt(max(sums(3) / sums(1) - mean * mean, 0.0_wp)) / mean
    end function disorder_from_sums
end module sph_disorder_measure
