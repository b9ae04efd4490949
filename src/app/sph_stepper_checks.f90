!> Checks of a start and a restart against what can run: the lattice's size against a rank's
!> neighbour list and the node's memory, and a checkpoint's geometry against the input's.
!> (A submodule of sph_stepper, as sph_stepper_shared explains; interfaces in sph_stepper.)
submodule (sph_stepper) sph_stepper_checks
    use sph_mpi_env, only: ranks_on_node
    use sph_logger, only: log_warn, int_text
    use sph_initial, only: lattice_sites_estimate
    use sph_memory, only: node_memory_bytes
    implicit none

contains

    !> Stop before laying a lattice that cannot run (collective). The fluid sites of &domain
    !> dx (a lower bound of the particles: walls, bodies and finer levels add to them),
    !> shared evenly over the ranks, must fit a rank's neighbour list, whose default-integer
    !> entries number about the neighbours within the kernel support per particle, and
    !> their memory, at least MIN_BYTES a particle (below every peak that bench/run
    !> measured: 481 and 1,123 bytes in 2D and 3D at 10^6), the node's. More than the node
    !> has available now but less than all of it: a warning. (A dx a thousand times too
    !> small used to run until the system killed the process, with no message.)
    module procedure check_lattice_size
        real(wp), parameter :: PI = acos(-1.0_wp), GB = 1024.0_wp**3
        real(wp), parameter :: MIN_BYTES(3) = [200.0_wp, 400.0_wp, 900.0_wp]
        real(wp) :: sites, per_rank, entries, ball, need, total_min, free_min
        integer(i8) :: total, available
        integer :: dim, on_node
        character(len=400) :: head, text
        dim = sim%cfg%domain%dimension
        sites = lattice_sites_estimate(sim%cfg)
        per_rank = sites / real(env%nranks, wp)
        ! the neighbours within the support: the volume of its ball in spacings
        ball = sim%phys%kernel%support / sim%cfg%domain%dx
        select case (dim)
        case (1)
            entries = 2.0_wp * ball
        case (2)
            entries = PI * ball**2
        case default
            entries = 4.0_wp / 3.0_wp * PI * ball**3
        end select
        entries = per_rank * max(entries, 1.0_wp)
        write(head, '(a,i0,a)') '&domain dx = ' // sci(sim%cfg%domain%dx) // &
            ' m lays about ' // sci(sites) // ' fluid particles in the box, ' // &
            sci(per_rank) // ' per rank on ', env%nranks, ' rank(s)'
        if (entries > real(huge(0), wp)) call fatal_collective('set-up', trim(head) // &
            ': more than a rank can hold (its neighbour list would have about ' // &
            sci(entries) // ' entries, at most 2^31 - 1); choose a larger dx or run on ' // &
            'more ranks')
        on_node = ranks_on_node(env)
        call node_memory_bytes(total, available)
        need = global_max(env, per_rank * real(on_node, wp) * MIN_BYTES(dim))
        ! the smallest node's (unknown: no limit)
        total_min = -global_max(env, -merge(real(total, wp), huge(1.0_wp), total > 0))
        free_min = -global_max(env, -merge(real(available, wp), huge(1.0_wp), available > 0))
        if (need > total_min) then
            write(text, '(a,f0.1,a,i0,a,f0.1,a)') trim(head) // ': they need at least ', &
                need / GB, ' GB on a node (', nint(MIN_BYTES(dim)), &
                ' bytes a particle or more), and a node has ', total_min / GB, &
                ' GB of memory; choose a larger dx or run on more nodes'
            call fatal_collective('set-up', trim(text))
        else if (need > free_min) then
            write(text, '(a,f0.1,a,f0.1,a)') 'set-up: ' // trim(head) // &
                ': they need at least ', need / GB, ' GB on a node, more than the ', &
                free_min / GB, ' GB available now; the system may stop the run'
            call log_warn(trim(text))
        end if
    contains
        !> x in scientific notation, two decimals, no padding.
        function sci(x) result(t)
            real(wp), intent(in) :: x
            character(len=:), allocatable :: t
            character(len=16) :: buffer
            write(buffer, '(es10.2)') x
            t = trim(adjustl(buffer))
        end function sci
    end procedure check_lattice_size

    !> How the geometry of a checkpoint's stored input differs from `cfg`'s ('' if it
    !> does not): the dimension, the box, the kind of every face and the &body groups.
    !> The checkpoint holds the wall and body particles laid for its own geometry, so a
    !> restart with another would run in a box half empty, without the walls its faces now
    !> ask for, or with fluid inside a new body (each of these ran before, to a health
    !> failure or to a wrong flow with exit status 0).
    module procedure geometry_mismatch
        integer :: dim, k
        real(wp) :: scale
        character(len=*), parameter :: TAIL = ' (continue with the checkpoint''s ' // &
            'geometry: its input is stored in it)'
        text = ''
        dim = cfg%domain%dimension
        if (stored%domain%dimension /= dim) then
            text = "the checkpoint is of a run in dimension " // &
                trim(int_text(int(stored%domain%dimension, i8))) // &
                ' but &domain dimension = ' // trim(int_text(int(dim, i8))) // TAIL
            return
        end if
        scale = maxval(cfg%domain%box_hi(1:dim) - cfg%domain%box_lo(1:dim))
        if (any(abs(stored%domain%box_lo(1:dim) - cfg%domain%box_lo(1:dim)) > &
            1.0e-12_wp * scale) .or. any(abs(stored%domain%box_hi(1:dim) - &
            cfg%domain%box_hi(1:dim)) > 1.0e-12_wp * scale)) then
            text = "the checkpoint's box differs from &domain box_lo / box_hi" // TAIL
            return
        end if
        do k = 1, 2 * dim
            if (trim(stored%domain%boundary(k)) /= trim(cfg%domain%boundary(k))) then
                text = "the checkpoint's face " // trim(int_text(int(k, i8))) // " is '" // &
                    trim(stored%domain%boundary(k)) // "' but &domain boundary(" // &
                    trim(int_text(int(k, i8))) // ") = '" // trim(cfg%domain%boundary(k)) // &
                    "'" // TAIL
                return
            end if
        end do
        if (size(stored%bodies) /= size(cfg%bodies)) then
            text = 'the checkpoint has ' // trim(int_text(int(size(stored%bodies), i8))) // &
                ' &body group(s) but the input ' // trim(int_text(int(size(cfg%bodies), i8))) &
                // TAIL
            return
        end if
        do k = 1, size(cfg%bodies)
            associate (a => stored%bodies(k), b => cfg%bodies(k))
                if (trim(a%shape) /= trim(b%shape) .or. a%axis /= b%axis .or. &
                    any(abs(a%centre - b%centre) > 1.0e-12_wp * scale) .or. &
                    abs(a%radius - b%radius) > 1.0e-12_wp * scale .or. &
                    any(abs(a%lo - b%lo) > 1.0e-12_wp * scale) .or. &
                    any(abs(a%hi - b%hi) > 1.0e-12_wp * scale)) then
                    text = "the checkpoint's &body " // trim(int_text(int(k, i8))) // &
                        " ('" // trim(a%name) // "') differs from the input's in shape, " // &
                        'place or size' // TAIL
                    return
                end if
            end associate
        end do
    end procedure geometry_mismatch
end submodule sph_stepper_checks
