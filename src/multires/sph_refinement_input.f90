!> Spatially varying resolution as read from input (thesis sec. 3.3): &refinement (one group:
!> the transition zone width, whether snapshots hold virtual particles, sub-cycling, how
!> virtual particles are made) and &region (repeated,
!> one per refinement region, numbered in file order): an axis-aligned box or slab, or the
!> band within a distance of a &body's surface, whose particles have spacing dx / 2**level.
!> Read by sph_config; turned into geometry by sph_zones.
!>
!> The checks that tie the regions to the rest of the case live here too: box faces inside
!> the domain on the coarse lattice (so the lattices of two levels meet without a gap), the
!> nesting of levels with a transition zone of margin, and the features that do not work with
!> refinement regions yet (mirror walls, in-run remeshing, initial particles from a file).
module sph_refinement_input
    use sph_kinds, only: wp, i8
    use sph_logger, only: int_text
    use sph_namelist, only: nml_group_t, real_text
    use sph_domain_input, only: domain_input_t
    use sph_physics_input, only: numerics_input_t
    use sph_remesh_input, only: remesh_input_t
    use sph_body_input, only: body_input_t
    use sph_kernel, only: kernel_id_from_name, kernel_support_factor, kernel_default_h_factor
    implicit none
    private
    public :: refinement_input_t, region_input_t, read_refinement_input, read_region_inputs
    public :: check_refinement, minimum_transition_width, MAX_REGION_LEVEL

    integer, parameter :: MAX_REGION_LEVEL = 3
    !> largest &refinement max_subcycles
    integer, parameter :: MAX_SUBCYCLES = 64
    integer, parameter :: name_len = 32
    !> tolerance, in units of dx, of the lattice alignment and of the nesting margins
    real(wp), parameter :: lattice_tol = 1.0e-9_wp

    type :: refinement_input_t
        real(wp) :: transition_width = 0.0_wp   !< m, as given; 0 = automatic
        logical :: write_virtual = .false.      !< snapshots also hold virtual particles
        !> a level's step may span up to this many steps of the finest level (a power of 2;
        !> 1 = every level takes the finest level's step)
        integer :: max_subcycles = 1
        !> how virtual particles are made from the other level: 'split' (2^dim children at
        !> +- dx/4 per coarse particle; coarse ones from the fine particles of lattice parity
        !> 0) or 'remesh' (sph_refine's construction and sph_coarsen's selection)
        character(len=8) :: virtual_rule = 'split'
        !> hold the real fluid's total mass and momentum balance over the levels
        !> (sph_level_balance)
        logical :: conserve = .true.
        !> with conserve: also remove the virtual particles' net push (the momentum part);
        !> .false. holds the mass only
        logical :: remove_push = .true.
        real(wp) :: width = 0.0_wp              !< m, resolved (set by check_refinement)
    end type refinement_input_t

    type :: region_input_t
        character(len=8) :: shape = 'box'       !< 'box' or 'body'
        real(wp) :: lo(3) = 0.0_wp, hi(3) = 0.0_wp   !< box corners (m)
        integer :: level = 1                    !< spacing dx / 2**level inside
        character(len=name_len) :: body = ''    !< shape 'body': the &body's name
        real(wp) :: distance = 0.0_wp           !< shape 'body': band around the body (m)
    end type region_input_t

contains

    !> Read the &refinement group (transition-zone width, virtual particles in snapshots).
    subroutine read_refinement_input(grp, ref)
        type(nml_group_t), intent(inout) :: grp
        type(refinement_input_t), intent(out) :: ref
        call grp%get_real('transition_width', ref%transition_width, 0.0_wp, min=0.0_wp, &
            unit='m', doc='width of each transition zone; 0 = one kernel support of level 0')
        call grp%get_logical('write_virtual', ref%write_virtual, .false., &
            doc='snapshots also hold the virtual particles (kind 2)')
        call grp%get_int('max_subcycles', ref%max_subcycles, 1, min=1, max=MAX_SUBCYCLES, &
            doc='a coarser level steps once per up to this many steps of the finest level, ' // &
            'as its own time-step limits allow (a power of 2; 1 = one shared time step)')
        call grp%get_string('virtual_rule', ref%virtual_rule, 'split', &
            choices=[character(len=8) :: 'split', 'remesh'], &
            doc='how virtual particles are made from the other level: split (each coarse ' // &
            'particle into 2^dim at +-dx/4 per axis, the fine ones of lattice parity 0 ' // &
            'into coarse ones; exact counts and masses) or remesh (the remeshing rules)')
        ! off by default with sub-cycling: on the cylinder with a fine ring, 3 of 5 sub-cycled
        ! runs with it stopped (a particle in the body, a density out of band, a collapsed
        ! step) between 4624 and 5995 s, none of 3 without it (multiresolution.md)
        call grp%get_logical('conserve', ref%conserve, ref%max_subcycles == 1, &
            doc='hold the real fluid''s total mass (one rescale after each transition ' // &
            'update) and momentum balance (the virtual particles'' net push removed from ' // &
            'the real particles next to them); .false. leaves both to the conversions; ' // &
            'default .true. with max_subcycles = 1, .false. with sub-cycling')
        ! in a channel the net push is about 1e-3 of the body force and its removal, at the
        ! particles next to the interfaces, tripled the fine band's error while the flow
        ! develops; around a body it reached 14 % and retarded the flow (multiresolution.md)
        call grp%get_logical('remove_push', ref%remove_push, .true., &
            doc='with conserve: also remove the virtual particles'' net push from the real ' // &
            'particles next to them (momentum); .false. holds the mass only and logs the ' // &
            'push as measured')
        if (.not. ref%conserve) call grp%note_if_given('remove_push', 'the push is ' // &
            'removed only with conserve = .true.')
        if (iand(ref%max_subcycles, ref%max_subcycles - 1) /= 0) call grp%error( &
            'max_subcycles', int_text(int(ref%max_subcycles, i8)) // ' is not a power of 2: ' // &
            'use 1, 2, 4, 8, ... up to ' // int_text(int(MAX_SUBCYCLES, i8)))
    end subroutine read_refinement_input

    !> Read every &region instance (grps, in file order) and check each on its own against the
    !> box and the bodies. Errors name the instance (`&region 2 (line 30) level: ...`).
    subroutine read_region_inputs(grps, dom, bodies, regions)
        type(nml_group_t), intent(inout) :: grps(:)
        type(domain_input_t), intent(in) :: dom
        type(body_input_t), intent(in) :: bodies(:)
        type(region_input_t), allocatable, intent(out) :: regions(:)
        integer :: r
        allocate(regions(size(grps)))
        do r = 1, size(grps)
            grps(r)%instance = r
            call read_region(grps(r), dom, bodies, regions(r))
        end do
    end subroutine read_region_inputs

    subroutine read_region(grp, dom, bodies, reg)
        type(nml_group_t), intent(inout) :: grp
        type(domain_input_t), intent(in) :: dom
        type(body_input_t), intent(in) :: bodies(:)
        type(region_input_t), intent(out) :: reg
        integer :: dim, a, b
        logical :: found

        call grp%get_string('shape', reg%shape, 'box', &
            choices=[character(len=4) :: 'box', 'body'], &
            doc="'box' (axis-aligned box or slab) or 'body' (a band around a &body)")
        call grp%get_real_array('lo', reg%lo, 0.0_wp, unit='m', &
            doc="lower corner of a 'box' region; may lie beyond the domain box")
        call grp%get_real_array('hi', reg%hi, 0.0_wp, unit='m', &
            doc="upper corner of a 'box' region; may lie beyond the domain box")
        call grp%get_int('level', reg%level, 1, min=1, max=MAX_REGION_LEVEL, &
            doc='particles inside have spacing dx / 2**level')
        call grp%get_string('body', reg%body, '', &
            doc="shape 'body': the name of a &body (unnamed bodies are 'body N')")
        call grp%get_real('distance', reg%distance, 0.0_wp, min=0.0_wp, unit='m', &
            doc="shape 'body': the region is within this distance of the body's surface")

        dim = min(max(dom%dimension, 2), 3)
        select case (trim(reg%shape))
        case ('box')
            do a = 1, dim
                if (.not. (reg%lo(a) < reg%hi(a))) then
                    call grp%error('lo(' // int_text(int(a, i8)) // ')', &
                        real_text(reg%lo(a)) // ' must be < hi(' // int_text(int(a, i8)) // &
                        ') = ' // real_text(reg%hi(a)) // ' (the corners of a box region)')
                    cycle
                end if
                ! wholly outside the box along an axis of walls, the region would hold no
                ! particle of its level (along a periodic axis its nearest image is taken)
                if (.not. dom%is_periodic(a) .and. .not. (reg%hi(a) > dom%box_lo(a) .and. &
                    reg%lo(a) < dom%box_hi(a))) then
                    call grp%error('lo(' // int_text(int(a, i8)) // ')', 'the region (' // &
                        real_text(reg%lo(a)) // ' to ' // real_text(reg%hi(a)) // &
                        ' m on axis ' // int_text(int(a, i8)) // ') lies outside the box (' // &
                        real_text(dom%box_lo(a)) // ' to ' // real_text(dom%box_hi(a)) // ' m)')
                    cycle
                end if
                if (dom%dx > 0.0_wp) then
                    call check_face(a, 'lo', reg%lo(a), reg%hi(a) - reg%lo(a))
                    call check_face(a, 'hi', reg%hi(a), reg%hi(a) - reg%lo(a))
                end if
            end do
        case ('body')
            ! (a negative distance is refused by the range check already: one message)
            if (reg%distance == 0.0_wp) call grp%error('distance', &
                "must be > 0 (m) for shape = 'body'")
            if (len_trim(reg%body) == 0) then
                call grp%error('body', "shape = 'body' needs the name of a &body" // &
                    body_list())
            else
                found = .false.
                do b = 1, size(bodies)
                    if (trim(bodies(b)%name) == trim(reg%body)) found = .true.
                end do
                if (.not. found) call grp%error('body', "no &body is named '" // &
                    trim(reg%body) // "'" // body_list())
            end if
        end select

    contains

        !> A face strictly inside the domain (along a periodic axis: any face, unless the box
        !> spans the whole period) must lie on a plane box_lo + k dx of the coarse lattice.
        subroutine check_face(ax, side, v, extent)
            integer, intent(in) :: ax
            character(len=*), intent(in) :: side
            real(wp), intent(in) :: v, extent
            real(wp) :: k, below, above
            if (dom%is_periodic(ax)) then
                if (extent >= dom%box_hi(ax) - dom%box_lo(ax)) return
            else if (.not. (v > dom%box_lo(ax) .and. v < dom%box_hi(ax))) then
                return
            end if
            k = (v - dom%box_lo(ax)) / dom%dx
            ! more than 10^9 spacings from box_lo: &domain refuses that box already (dx below
            ! 1e-9 of its length), and no lattice check means anything there
            if (abs(k) > 1.0e9_wp) return
            if (abs(v - (dom%box_lo(ax) + anint(k) * dom%dx)) <= lattice_tol * dom%dx) return
            k = aint(k) - merge(1.0_wp, 0.0_wp, aint(k) > k)
            below = dom%box_lo(ax) + k * dom%dx
            above = dom%box_lo(ax) + (k + 1.0_wp) * dom%dx
            call grp%error(side // '(' // int_text(int(ax, i8)) // ')', real_text(v) // &
                ' is not on the coarse lattice (box_lo + k dx, dx = ' // real_text(dom%dx) // &
                '); the nearest allowed values are ' // nice(below) // ' and ' // &
                nice(above) // ' m')
        end subroutine check_face

        function body_list() result(text)
            character(len=:), allocatable :: text
            integer :: j
            if (size(bodies) == 0) then
                text = ' (the input has no &body)'
                return
            end if
            text = ' (bodies:'
            do j = 1, size(bodies)
                text = text // " '" // trim(bodies(j)%name) // "'"
            end do
            text = text // ')'
        end function body_list
    end subroutine read_region

    !> One kernel support of level 0: the narrowest transition zone (m), and the automatic one.
    !> 0 when the kernel name is unknown (already reported by &numerics).
    real(wp) function minimum_transition_width(dom, num) result(width)
        type(domain_input_t), intent(in) :: dom
        type(numerics_input_t), intent(in) :: num
        integer :: id
        real(wp) :: h_factor
        width = 0.0_wp
        id = kernel_id_from_name(num%kernel)
        if (id == 0) return
        h_factor = num%h_factor
        if (h_factor <= 0.0_wp) h_factor = kernel_default_h_factor(id)
        width = kernel_support_factor(id) * h_factor * dom%dx
    end function minimum_transition_width

    !> The checks that span groups, made once every group has been read without error: the
    !> transition width (resolved into ref%width), the nesting of the levels, and the features
    !> refused with refinement regions. Each error goes to the group that owns its key.
    subroutine check_refinement(ref_grp, region_grps, dom_grp, num_grp, rem_grp, ref, &
            regions, dom, num, rem)
        type(nml_group_t), intent(inout) :: ref_grp, region_grps(:), dom_grp, num_grp, rem_grp
        type(refinement_input_t), intent(inout) :: ref
        type(region_input_t), intent(in) :: regions(:)
        type(domain_input_t), intent(in) :: dom
        type(numerics_input_t), intent(in) :: num
        type(remesh_input_t), intent(in) :: rem
        real(wp) :: minimum
        integer :: r
        character(len=*), parameter :: not_yet = ' is not supported with &region (refinement ' // &
            'regions) yet'

        minimum = minimum_transition_width(dom, num)
        ref%width = ref%transition_width
        if (ref%width <= 0.0_wp) ref%width = minimum
        if (ref%transition_width > 0.0_wp .and. &
            ref%transition_width < minimum * (1.0_wp - lattice_tol)) call ref_grp%error( &
            'transition_width', real_text(ref%transition_width) // ' m is narrower than one ' // &
            'kernel support of level 0: must be >= ' // nice(minimum) // ' m (or 0 = ' // &
            'automatic, that support)')
        ! (a zone wider than the box covers all of it, and the refinement of a uniform state
        ! placed periodic images that far away: 1e10 m overflowed the cell index)
        associate (largest => maxval(dom%box_hi(1:dom%dimension) - dom%box_lo(1:dom%dimension)))
            if (ref%transition_width > largest) call ref_grp%error('transition_width', &
                real_text(ref%transition_width) // ' m is wider than the box (its largest ' // &
                'length ' // nice(largest) // ' m): must be at most that (or 0 = automatic, ' // &
                'one kernel support of level 0)')
        end associate

        if (size(regions) == 0) then
            if (ref_grp%line > 0) call ref_grp%error('(group)', 'given without any &region: ' // &
                'nothing to refine; add &region groups or leave &refinement out')
            return
        end if

        if (trim(num%wall_model) == 'mirror' .or. trim(num%wall_model) == 'repulsive_mirror') &
            call num_grp%error('wall_model', "'" // trim(num%wall_model) // "'" // not_yet // &
                "; with &region use 'morris' or 'repulsive'")
        if (trim(rem%mode) /= 'none') call rem_grp%error('mode', "'" // trim(rem%mode) // &
            "' (remeshing during the run)" // not_yet // "; with &region use 'none'")
        if (trim(ref%virtual_rule) == 'remesh') then
            do r = 1, size(regions)
                call check_remesh_rule_faces(r)
            end do
        end if
        if (len_trim(dom%initial_particles) > 0) call dom_grp%error('initial_particles', &
            'initial particles from a file' // not_yet // "; with &region leave it '' " // &
            '(the lattice)')

        ! (a summed density of a real particle next to the interface counts the virtual
        ! particles within one support of it only as far as the zone reaches: the shipped
        ! Poiseuille band ran with a cross-flow, 31.6 % off at 0.01 s against 0.19 % with
        ! continuity)
        if (trim(num%density_method) == 'summation') call num_grp%error('density_method', &
            "'summation'" // not_yet // "; with &region use 'continuity'")
        if (ref%max_subcycles > 1) call check_subcycling()
        ! the multi-resolution Verlet step (sph_stepper) has no shifting stage
        if (trim(num%integrator) == 'verlet' .and. trim(num%shifting) /= 'none') &
            call num_grp%error('shifting', "'" // trim(num%shifting) // "' with " // &
            "integrator = 'verlet'" // not_yet // "; use shifting = 'none' or integrator = " // &
            "'predictor_corrector'")
        ! nor a density filter
        if (trim(num%integrator) == 'verlet' .and. trim(num%density_filter) /= 'none') &
            call num_grp%error('density_filter', "'" // trim(num%density_filter) // &
            "' with integrator = 'verlet'" // not_yet // "; use density_filter = 'none' " // &
            "or integrator = 'predictor_corrector'")

        do r = 1, size(regions)
            if (regions(r)%level >= 2) call check_nesting(r)
        end do

    contains

        !> Sub-cycling is built on velocity Verlet with integrated densities and no shifting
        !> (sph_integrator): the predictor-corrector's mid-step rates, a summed density and
        !> a shift after the step all need every level at the same time.
        subroutine check_subcycling()
            character(len=:), allocatable :: needs
            needs = int_text(int(ref%max_subcycles, i8)) // ' (sub-cycling) needs '
            if (trim(num%integrator) /= 'verlet') call ref_grp%error('max_subcycles', &
                needs // "&numerics integrator = 'verlet' (it is '" // &
                trim(num%integrator) // "'); or set max_subcycles = 1")
            if (trim(num%density_method) /= 'continuity') call ref_grp%error('max_subcycles', &
                needs // "&numerics density_method = 'continuity' (it is '" // &
                trim(num%density_method) // "'); or set max_subcycles = 1")
            if (trim(num%shifting) /= 'none') call ref_grp%error('max_subcycles', &
                needs // "&numerics shifting = 'none' (it is '" // trim(num%shifting) // &
                "'); or set max_subcycles = 1")
        end subroutine check_subcycling

        !> Region r (level L >= 2) lies inside a region of level L - 1 with a margin of at
        !> least the transition width where its boundary is strictly inside the domain:
        !> box in box, or body in body around the same body.
        subroutine check_nesting(rr)
            integer, intent(in) :: rr
            integer :: q, level
            logical :: other_shape
            level = regions(rr)%level
            other_shape = .false.
            do q = 1, size(regions)
                if (q == rr .or. regions(q)%level /= level - 1) cycle
                if (trim(regions(q)%shape) /= trim(regions(rr)%shape)) then
                    other_shape = .true.
                    cycle
                end if
                select case (trim(regions(rr)%shape))
                case ('box')
                    if (box_in_box(regions(rr), regions(q))) return
                case ('body')
                    if (trim(regions(q)%body) /= trim(regions(rr)%body)) then
                        other_shape = .true.
                        cycle
                    end if
                    if (regions(rr)%distance + ref%width <= &
                        regions(q)%distance + lattice_tol * dom%dx) return
                end select
            end do
            if (other_shape) then
                call region_grps(rr)%error('level', 'a level ' // int_text(int(level, i8)) // &
                    " region must lie inside a level " // int_text(int(level - 1, i8)) // &
                    " region of the same kind (a box in a box, or a band around the same " // &
                    "body in a wider one); other nestings are not supported yet")
            else
                call region_grps(rr)%error('level', 'a level ' // int_text(int(level, i8)) // &
                    ' region must lie inside a level ' // int_text(int(level - 1, i8)) // &
                    ' region with a margin of at least the transition width (' // &
                    nice(ref%width) // ' m) wherever its boundary is inside the domain; ' // &
                    'no level ' // &
                    int_text(int(level - 1, i8)) // ' region holds it so')
            end if
        end subroutine check_nesting

        !> virtual_rule = 'remesh': a box face on a periodic face is refused. That rule's
        !> virtual particles take their ids from their sources', in which a periodic image is
        !> marked by its side of the box: when a source crosses the periodic face, the slot it
        !> gives (where the rule would make its virtual now) changes id, and a virtual carried
        !> across a region's face lying there finds no slot and does not turn real. With the
        !> face on box_hi, 398 real coarse particles were left where 400 were due, and the
        !> error at 0.5 s was 0.79 % against 0.34 % for the same region moved by whole
        !> spacings, on every rank count (fz39). The split rule (the default) is unaffected.
        subroutine check_remesh_rule_faces(rr)
            integer, intent(in) :: rr
            integer :: a
            character(len=2) :: side
            if (trim(regions(rr)%shape) == 'body') return
            do a = 1, min(max(dom%dimension, 2), 3)
                if (.not. dom%is_periodic(a)) cycle
                if (regions(rr)%hi(a) - regions(rr)%lo(a) >= dom%box_hi(a) - dom%box_lo(a)) &
                    cycle
                side = ''
                if (on_periodic_face(regions(rr)%hi(a), a)) side = 'hi'
                if (on_periodic_face(regions(rr)%lo(a), a)) side = 'lo'
                if (len_trim(side) == 0) cycle
                call region_grps(rr)%error(side // '(' // int_text(int(a, i8)) // ')', &
                    'puts a face of the region on the periodic face of axis ' // &
                    int_text(int(a, i8)) // ' (box_lo = ' // real_text(dom%box_lo(a)) // &
                    ', box_hi = ' // real_text(dom%box_hi(a)) // "), where &refinement " // &
                    "virtual_rule = 'remesh' does not work yet: move the region by a whole " // &
                    'number of spacings (dx = ' // real_text(dom%dx) // '), let it cross ' // &
                    "that face, or use virtual_rule = 'split'")
                return
            end do
        end subroutine check_remesh_rule_faces

        !> Whether v lies on a periodic face of axis ax (box_lo + a whole number of periods).
        logical function on_periodic_face(v, ax)
            real(wp), intent(in) :: v
            integer, intent(in) :: ax
            real(wp) :: periods, length
            length = dom%box_hi(ax) - dom%box_lo(ax)
            periods = (v - dom%box_lo(ax)) / length
            on_periodic_face = abs(periods - anint(periods)) * length <= lattice_tol * dom%dx
        end function on_periodic_face

        !> inner lies in outer with a margin of ref%width on every side inside the domain.
        logical function box_in_box(inner, outer) result(inside)
            type(region_input_t), intent(in) :: inner, outer
            real(wp) :: w, tol, length, il, ih, ol, oh, shift
            integer :: a
            w = ref%width
            tol = lattice_tol * dom%dx
            inside = .false.
            do a = 1, min(max(dom%dimension, 2), 3)
                length = dom%box_hi(a) - dom%box_lo(a)
                if (dom%is_periodic(a)) then
                    if (outer%hi(a) - outer%lo(a) >= length) cycle        ! outer spans the axis
                    if (inner%hi(a) - inner%lo(a) >= length) return       ! inner does, outer not
                    ! the image of inner whose widened lower face is nearest above outer's
                    ! (floored as a real: the ratio may exceed an integer's range)
                    shift = (inner%lo(a) - w - outer%lo(a) + tol) / length
                    shift = -length * (aint(shift) - merge(1.0_wp, 0.0_wp, aint(shift) > shift))
                    if (inner%hi(a) + w + shift > outer%hi(a) + tol) return
                else
                    ! clipped to the box: a face at or beyond a wall needs no margin
                    il = max(inner%lo(a), dom%box_lo(a))
                    ih = min(inner%hi(a), dom%box_hi(a))
                    ol = max(outer%lo(a), dom%box_lo(a))
                    oh = min(outer%hi(a), dom%box_hi(a))
                    if (il > dom%box_lo(a)) then
                        if (ol > il - w + tol) return
                    else if (ol > dom%box_lo(a)) then
                        return
                    end if
                    if (ih < dom%box_hi(a)) then
                        if (oh < ih + w - tol) return
                    else if (oh < dom%box_hi(a)) then
                        return
                    end if
                end if
            end do
            inside = .true.
        end function box_in_box
    end subroutine check_refinement

    !> x to 12 significant digits, shortest form: 0.15 for box_lo + 3 dx = 0.15000000000000002.
    function nice(x) result(text)
        real(wp), intent(in) :: x
        character(len=:), allocatable :: text
        character(len=32) :: buf
        real(wp) :: rounded
        write(buf, '(es32.11e3)') x
        read(buf, *) rounded
        text = real_text(rounded)
    end function nice
end module sph_refinement_input
