!> Relaxation of a new particle set before the transfer (same-level remeshing of a disordered
!> flow). Serial, no MPI: the caller hands in the new positions followed by their periodic
!> images and their mirrors across solids (the repulsors that keep the first row off a wall).
!>
!> Why. A selected set (sph_coarsen's class 1 and fill on a refined disordered flow) has the
!> right count but uneven volumes: its Voronoi areas vary by 25-30 % (coefficient of
!> variation) against 8-13 % for the flow it came from, because a maximal set at a fixed
!> radius packs randomly. The transfer hands each new particle the mass of its volume, so the
!> masses vary alike (0.5-1.4 m0 between the 5th and 95th percentiles on the L/50 cylinder
!> flow) and every remesh puts that noise into the flow.
!>
!> Rule. Each pass moves every particle down the gradient of the particle concentration
!> C(x) = sum_b V W(x - x_b) (Lind et al. 2012's shifting, used here as a static smoother):
!> dx_a = -RELAX_COEFFICIENT h^2 sum_b V grad_a W_ab, V = dx^dim, cubic B-spline with h =
!> 1.3 dx, each move capped at RELAX_MAX_STEP dx. A uniform arrangement has no gradient; a
!> clump pushes its members apart into the gaps around it. RELAX_PASSES passes bring the
!> Voronoi CoV of the cylinder flow's selected set from 0.25 to about 0.12 (the flow's own
!> 0.08-0.13) while the particles move by a fraction of a spacing, so the disorder stays that
!> of the flow, not a lattice.
module sph_remesh_relax
    use sph_kinds, only: wp
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_kernel, only: kernel_t, kernel_create, KERNEL_CUBIC
    implicit none
    private
    public :: relax_displacements, RELAX_PASSES, RELAX_H_FACTOR

    integer, parameter :: RELAX_PASSES = 10
    real(wp), parameter :: RELAX_H_FACTOR = 1.3_wp
    real(wp), parameter :: RELAX_COEFFICIENT = 0.3_wp
    real(wp), parameter :: RELAX_MAX_STEP = 0.2_wp

contains

    !> One pass: displacements d(:, 1:n) of the points y(:, 1:n) of spacing dx, the points
    !> y(:, n + 1:ny) (images and mirrors) pushing but not moved.
    subroutine relax_displacements(dim, n, ny, y, dx, d)
        integer, intent(in) :: dim, n, ny
        real(wp), intent(in) :: y(:, :), dx
        real(wp), intent(out) :: d(:, :)
        type(neighbour_list_t) :: nl
        type(kernel_t) :: kernel
        real(wp) :: h, vol, r, s(3), rij(3), step
        ! one point's partners: distances, unit vectors, dW/dr (the kernel evaluated per
        ! point in one batch: a call per pair through sph_kernel cost a fifth of the pass)
        real(wp), allocatable :: rs(:), unit(:, :), dw(:)
        integer :: a, p, b, m
        h = RELAX_H_FACTOR * dx
        vol = dx**dim
        d(:, 1:n) = 0.0_wp
        if (n == 0) return
        kernel = kernel_create(KERNEL_CUBIC, dim, h)
        call build_neighbour_list(y, ny, n, dim, 2.0_wp * h, nl)
        m = maxval(nl%start(2:n + 1) - nl%start(1:n))
        allocate(rs(m), unit(3, m), dw(m))
        do a = 1, n
            m = 0
            do p = nl%start(a), nl%start(a + 1) - 1
                b = nl%index(p)
                if (b == a) cycle
                rij = y(:, a) - y(:, b)
                rij(dim + 1:) = 0.0_wp
                r = norm2(rij)
                if (r <= 0.0_wp .or. r >= 2.0_wp * h) cycle
                m = m + 1
                rs(m) = r
                unit(:, m) = rij / r
            end do
            call kernel%dwdr_many(rs(1:m), dw(1:m))
            s = 0.0_wp
            do p = 1, m
                s = s + vol * dw(p) * unit(:, p)
            end do
            d(:, a) = -RELAX_COEFFICIENT * h * h * s
            step = norm2(d(:, a))
            if (step > RELAX_MAX_STEP * dx) d(:, a) = d(:, a) * (RELAX_MAX_STEP * dx / step)
        end do
    end subroutine relax_displacements
end module sph_remesh_relax
