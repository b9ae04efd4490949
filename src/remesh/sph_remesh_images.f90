!> The particles plus their periodic images near the box, for neighbour searches across
!> periodic faces in refinement and coarsening (serial; a parallel run passes particles with
!> their halo instead and asks for no images), and their mirror images across solids for the
!> remesh driver's transfer and relaxation and the transition zones (no MPI calls).
module sph_remesh_images
    use sph_kinds, only: wp
    use sph_solids, only: solids_t, solid_distance, solid_reflect, corner_planes, &
        MAX_CORNER_COMBOS, solid_mirrors, solid_velocity
    implicit none
    private
    public :: with_periodic_images, relative_to, mirror_shifts, with_images, &
        with_mirrors_and_images, with_mirrors

contains

    !> xa(:, 1:n) = x(:, 1:n) (z = 0 in 2D), followed, when periodic, by every image shifted by
    !> whole box lengths per axis that lies within `reach` of [0, box); orig(k) is the
    !> particle that point k copies; ntot points in all. with_images for a box at the origin,
    !> periodic on every axis or on none.
    subroutine with_periodic_images(dim, n, x, periodic, box, reach, xa, orig, ntot)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), box(3), reach
        logical, intent(in) :: periodic
        real(wp), allocatable, intent(out) :: xa(:, :)
        integer, allocatable, intent(out) :: orig(:)
        integer, intent(out) :: ntot
        integer :: a
        call with_images(dim, [0.0_wp, 0.0_wp, 0.0_wp], box, [(periodic .and. a <= dim, &
            a = 1, 3)], n, x, reach, xa, orig, ntot)
        xa(dim + 1:, 1:ntot) = 0.0_wp
    end subroutine with_periodic_images

    !> y(:, 1:n) = x(:, 1:n) - box_lo (at least one column), orig(k) = k: the start of a set
    !> with_mirrors appends to.
    subroutine relative_to(box_lo, x, n, y, orig)
        real(wp), intent(in) :: box_lo(3), x(:, :)
        integer, intent(in) :: n
        real(wp), allocatable, intent(out) :: y(:, :)
        integer, allocatable, intent(out) :: orig(:)
        integer :: i
        allocate(y(3, max(n, 1)), orig(max(n, 1)))
        do i = 1, n
            y(:, i) = x(:, i) - box_lo
            orig(i) = i
        end do
    end subroutine relative_to

    !> Per point 1..n, the farthest of its mirrors y(:, n + 1:ny) lies from it (orig(k): the
    !> point mirror k mirrors, the identity on 1..n: with_mirrors' layout); 0 without one.
    function mirror_shifts(y, orig, n, ny) result(shift)
        real(wp), intent(in) :: y(:, :)
        integer, intent(in) :: orig(:), n, ny
        real(wp) :: shift(n)
        integer :: k
        shift = 0.0_wp
        do k = n + 1, ny
            shift(orig(k)) = max(shift(orig(k)), norm2(y(:, k) - y(:, orig(k))))
        end do
    end function mirror_shifts

    !> y(:, 1:ny): the points of xs(:, 1:ns) (relative to box_lo) followed by their images
    !> on the periodic axes (any combination of shifts by whole box lengths) within `dist` of
    !> the box [0, L); orig(k): the point that point k copies.
    subroutine with_images(dim, box_lo, box_hi, periodic, ns, xs, dist, y, orig, ny)
        integer, intent(in) :: dim, ns
        real(wp), intent(in) :: box_lo(3), box_hi(3), xs(:, :), dist
        logical, intent(in) :: periodic(3)
        real(wp), allocatable, intent(out) :: y(:, :)
        integer, allocatable, intent(out) :: orig(:)
        integer, intent(out) :: ny
        integer :: kmax(3), s(3), i, a, cap, s1, s2, s3
        real(wp) :: len_(3), z(3)
        real(wp), allocatable :: yt(:, :)
        integer, allocatable :: ot(:)
        len_ = 1.0_wp
        kmax = 0
        do a = 1, dim
            len_(a) = box_hi(a) - box_lo(a)
            if (periodic(a)) kmax(a) = ceiling(dist / len_(a))
        end do
        cap = max(ns, 1) * product(2 * kmax + 1)
        allocate(y(3, cap), orig(cap))
        ny = ns
        y(:, 1:ns) = xs(:, 1:ns)
        orig(1:ns) = [(i, i = 1, ns)]
        do s3 = -kmax(3), kmax(3)
            do s2 = -kmax(2), kmax(2)
                do s1 = -kmax(1), kmax(1)
                    s = [s1, s2, s3]
                    if (all(s == 0)) cycle
                    do i = 1, ns
                        z = xs(:, i) + real(s, wp) * len_
                        z(dim + 1:) = 0.0_wp
                        if (any(z(1:dim) < -dist .or. z(1:dim) >= len_(1:dim) + dist)) cycle
                        ny = ny + 1
                        y(:, ny) = z
                        orig(ny) = i
                    end do
                end do
            end do
        end do
        allocate(yt(3, ny), ot(ny))
        yt = y(:, 1:ny)
        ot = orig(1:ny)
        call move_alloc(yt, y)
        call move_alloc(ot, orig)
    end subroutine with_images

    !> y(:, 1:ny): the points xs(:, 1:ns) (relative to box_lo, in the box), then their mirror
    !> images across every solid within mirror_dist of its surface (with_mirrors), then the
    !> periodic images of both within image_dist of the box (with_images); orig(k): the point
    !> of xs that point k copies. Mirrors first: a mirror's images are the mirrors of the
    !> images (a solid repeats with the box), and every point, mirror or not, is kept by the
    !> same rule (within image_dist of the box), so the old and the new sets are cut at the same
    !> place. Mirroring the images instead mirrors points near the edge of the reach across a
    !> periodic image of a body, deep into it, where the old and new images were cut
    !> differently: mirrors with no partner at all (issue 10, Morris' cylinder: "new particles
    !> receive no mass" refining L/25, "old particles have no new particle" coarsening L/50).
    !> moves_with (optional): orig(k) for the points that are xs's own or their periodic
    !> images (each moves as its point does), 0 for the mirrors and their images.
    subroutine with_mirrors_and_images(dim, box_lo, box_hi, periodic, solids, mirror_dist, &
            image_dist, ns, xs, y, orig, ny, moves_with)
        integer, intent(in) :: dim, ns
        real(wp), intent(in) :: box_lo(3), box_hi(3), mirror_dist, image_dist, xs(:, :)
        logical, intent(in) :: periodic(3)
        type(solids_t), intent(in), optional :: solids
        real(wp), allocatable, intent(out) :: y(:, :)
        integer, allocatable, intent(out) :: orig(:)
        integer, intent(out) :: ny
        integer, allocatable, intent(out), optional :: moves_with(:)
        real(wp), allocatable :: ym(:, :)
        integer, allocatable :: om(:), oi(:)
        integer :: nm, i
        nm = ns
        allocate(ym(3, max(ns, 1)), om(max(ns, 1)))
        ym(:, 1:ns) = xs(:, 1:ns)
        om(1:ns) = [(i, i = 1, ns)]
        if (present(solids)) call with_mirrors(dim, solids, box_lo, mirror_dist, ym, om, nm)
        call with_images(dim, box_lo, box_hi, periodic, nm, ym, image_dist, y, oi, ny)
        orig = om(oi(1:ny))
        if (present(moves_with)) moves_with = merge(orig, 0, oi(1:ny) <= ns)
    end subroutine with_mirrors_and_images

    !> Append to y(:, 1:ny) the mirror images, across every solid, of its points (relative to
    !> box_lo) that lie in the fluid within `dist` of that solid's surface; orig follows. A
    !> point within `dist` of two (three) planes at right angles, a box's corner, is also
    !> mirrored across both (all three), as sph_refine's construction is: without those
    !> images the transfer handed the corner particles of a refined lattice box 1-4 % more
    !> mass than the others.
    !> velocity (optional, 3 x ny on entry): the points' velocities, extended over the mirrors
    !> as a no-slip wall has the flow: the image across a solid moving at v_s carries
    !> 2 v_s - v (the velocity odd about the wall's, so that an interpolation across the
    !> surface sees the shear profile go on through the wall's velocity), an image across
    !> two or three planes the composition of those. (Carrying v itself, the flow's profile
    !> even about the wall, every transfer raised the velocity next to a wall: a same-level
    !> remesh every 20 steps of a channel with three bodies ran its flow 12 % faster with
    !> the positions left unchanged.)
    subroutine with_mirrors(dim, solids, box_lo, dist, y, orig, ny, velocity)
        integer, intent(in) :: dim
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: box_lo(3), dist
        real(wp), allocatable, intent(inout) :: y(:, :)
        integer, allocatable, intent(inout) :: orig(:)
        integer, intent(inout) :: ny
        real(wp), allocatable, intent(inout), optional :: velocity(:, :)
        real(wp), allocatable :: yt(:, :), vt(:, :)
        integer, allocatable :: ot(:)
        integer :: combos(3, MAX_CORNER_COMBOS)
        integer :: s, i, n0, ns, n_corner, n_combos, c
        real(wp) :: d, z(3)
        if (.not. allocated(solids%list)) return
        ns = size(solids%list)
        if (ns == 0) return
        n0 = ny
        ! the corner images first counted (planes at right angles: at most three of them near
        ! a point of a box, 3 pairs and 1 triple)
        n_corner = 0
        do i = 1, n0
            call corner_planes(solids, y(:, i) + box_lo, dist, combos, n_combos)
            n_corner = n_corner + n_combos
        end do
        allocate(yt(3, n0 * (ns + 1) + n_corner), ot(n0 * (ns + 1) + n_corner))
        yt(:, 1:n0) = y(:, 1:n0)
        ot(1:n0) = orig(1:n0)
        if (present(velocity)) then
            allocate(vt(3, n0 * (ns + 1) + n_corner))
            vt(:, 1:n0) = velocity(:, 1:n0)
        end if
        do s = 1, ns
            do i = 1, n0
                d = solid_distance(solids%list(s), y(:, i) + box_lo)
                if (d < 0.0_wp .or. d >= dist) cycle
                if (.not. solid_mirrors(solids%list(s), y(:, i) + box_lo, others=solids, &
                    self=s)) cycle
                ny = ny + 1
                yt(:, ny) = solid_reflect(solids%list(s), y(:, i) + box_lo) - box_lo
                yt(dim + 1:, ny) = 0.0_wp
                ot(ny) = orig(i)
                if (present(velocity)) vt(:, ny) = 2.0_wp * solid_velocity(solids%list(s), &
                    y(:, i) + box_lo) - velocity(:, i)
            end do
        end do
        do i = 1, n0
            call corner_planes(solids, y(:, i) + box_lo, dist, combos, n_combos)
            do c = 1, n_combos
                z = solid_reflect(solids%list(combos(2, c)), &
                    solid_reflect(solids%list(combos(1, c)), y(:, i) + box_lo))
                if (combos(3, c) /= 0) z = solid_reflect(solids%list(combos(3, c)), z)
                ny = ny + 1
                yt(:, ny) = z - box_lo
                yt(dim + 1:, ny) = 0.0_wp
                ot(ny) = orig(i)
                if (present(velocity)) call corner_velocity(combos(:, c), velocity(:, i), &
                    y(:, i) + box_lo, vt(:, ny))
            end do
        end do
        y = yt(:, 1:ny)
        orig = ot(1:ny)
        if (present(velocity)) velocity = vt(:, 1:ny)

    contains

        !> The velocity of x's image across the planes of combo (2 or 3 of them, in order).
        subroutine corner_velocity(combo, v, x, vc)
            integer, intent(in) :: combo(3)
            real(wp), intent(in) :: v(3), x(3)
            real(wp), intent(out) :: vc(3)
            integer :: k
            vc = v
            do k = 1, 3
                if (combo(k) == 0) exit
                vc = 2.0_wp * solid_velocity(solids%list(combo(k)), x) - vc
            end do
        end subroutine corner_velocity

    end subroutine with_mirrors
end module sph_remesh_images
