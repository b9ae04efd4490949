!> The particles plus their periodic images near the box, for neighbour searches across
!> periodic faces in refinement and coarsening (serial; a parallel run passes particles with
!> their halo instead and asks for no images).
module sph_remesh_images
    use sph_kinds, only: wp
    implicit none
    private
    public :: with_periodic_images

contains

    !> xa(:, 1:n) = x(:, 1:n) (z = 0 in 2D), followed, when periodic, by every image shifted by
    !> a combination of -box, 0, +box per axis that lies within `reach` of [0, box);
    !> orig(k) is the particle that point k copies; ntot points in all.
    subroutine with_periodic_images(dim, n, x, periodic, box, reach, xa, orig, ntot)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), box(3), reach
        logical, intent(in) :: periodic
        real(wp), allocatable, intent(out) :: xa(:, :)
        integer, allocatable, intent(out) :: orig(:)
        integer, intent(out) :: ntot
        integer :: n_shifts, s, i, shift(3)
        real(wp) :: y(3)
        n_shifts = 0
        if (periodic) n_shifts = 3**dim
        allocate(xa(3, n * max(n_shifts, 1)), orig(n * max(n_shifts, 1)))
        xa(:, 1:n) = x(:, 1:n)
        xa(dim + 1:, 1:n) = 0.0_wp
        orig(1:n) = [(i, i = 1, n)]
        ntot = n
        do s = 0, n_shifts - 1
            shift = 0
            shift(1) = mod(s, 3) - 1
            if (dim >= 2) shift(2) = mod(s / 3, 3) - 1
            if (dim == 3) shift(3) = s / 9 - 1
            if (all(shift == 0)) cycle
            do i = 1, n
                y = xa(:, i) + real(shift, wp) * box
                if (any(y(1:dim) < -reach .or. y(1:dim) >= box(1:dim) + reach)) cycle
                ntot = ntot + 1
                xa(:, ntot) = y
                orig(ntot) = i
            end do
        end do
    end subroutine with_periodic_images
end module sph_remesh_images
