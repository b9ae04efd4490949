!> Checks of a start and a restart against what can run: the lattice's size against a rank's
!> neighbour list and the node's memory, and a checkpoint's geometry against the input's.
!> (A submodule of sph_stepper, as sph_stepper_shared explains; interfaces in sph_stepper.)
submodule (sph_stepper) sph_stepper_checks
    use sph_mpi_env, only: ranks_on_node
    use sph_logger, only: log_warn, int_text, sci_text
    use sph_initial, only: lattice_sites_estimate, lattice_mass_factor
    use sph_memory, only: node_memory_bytes
    use sph_physics, only: physics_from_config
    use sph_walls, only: wall_layers
    use sph_text_lines, only: next_line
    implicit none

contains

    !> Stop before laying a lattice that cannot run (collective). The fluid sites of &domain
    !> dx (a lower bound of the particles: walls, bodies and finer levels add to them),
    !> shared evenly over the ranks, must fit (fit_on_nodes). More than the node has
    !> available now but less than all of it: a warning. (A dx a thousand times too small
    !> used to run until the system killed the process, with no message.)
    module procedure check_lattice_size
        real(wp) :: sites
        character(len=:), allocatable :: problem, warning
        character(len=400) :: head
        sites = lattice_sites_estimate(sim%cfg)
        write(head, '(a,i0,a)') '&domain dx = ' // sci_text(sim%cfg%domain%dx) // &
            ' m lays about ' // sci_text(sites) // ' fluid particles in the box, ' // &
            sci_text(sites / real(env%nranks, wp)) // ' per rank on ', env%nranks, ' rank(s)'
        call fit_on_nodes(sim, env, sites, 0.0_wp, problem, warning)
        if (len(problem) > 0) call fatal_collective('set-up', trim(head) // problem // &
            '; choose a larger dx or run on more ' // merge('ranks', 'nodes', &
            index(problem, 'neighbour list') > 0))
        if (len(warning) > 0) call log_warn('set-up: ' // trim(head) // warning // &
            '; the system may stop the run')
    end procedure check_lattice_size

    !> Whether `particles` (over all ranks, shared evenly) can run (collective): problem
    !> (': ...', '' if they can) when a rank's neighbour list, whose default-integer entries
    !> number about the neighbours within the kernel support per particle, would pass
    !> 2^31 - 1, or when their memory, at least MIN_BYTES a particle (below every peak that
    !> bench/run measured: 481 and 1,123 bytes in 2D and 3D at 10^6), and rank0_bytes more
    !> on rank 0's node exceed the smallest node's; warning (': ...') when that is more than
    !> a node has available now.
    module procedure fit_on_nodes
        real(wp), parameter :: PI = acos(-1.0_wp)
        real(wp), parameter :: MIN_BYTES(3) = [200.0_wp, 400.0_wp, 900.0_wp]
        real(wp) :: per_rank, entries, ball, need, total_min, free_min
        integer(i8) :: total, available
        integer :: dim, on_node
        character(len=16) :: text
        problem = ''
        warning = ''
        dim = sim%cfg%domain%dimension
        per_rank = particles / real(env%nranks, wp)
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
        if (entries > real(huge(0), wp)) then
            problem = ': more than a rank can hold (its neighbour list would have about ' // &
                sci_text(entries) // ' entries, at most 2^31 - 1)'
            return
        end if
        on_node = ranks_on_node(env)
        call node_memory_bytes(total, available)
        need = per_rank * real(on_node, wp) * MIN_BYTES(dim)
        if (env%rank == 0) need = need + rank0_bytes
        need = global_max(env, need)
        ! the smallest node's (unknown: no limit)
        total_min = -global_max(env, -merge(real(total, wp), huge(1.0_wp), total > 0))
        free_min = -global_max(env, -merge(real(available, wp), huge(1.0_wp), available > 0))
        if (need > total_min) then
            write(text, '(i0)') nint(MIN_BYTES(dim))
            problem = ': they need at least ' // bytes_text(need) // ' on a node (' // &
                trim(text) // ' bytes a particle or more'
            if (rank0_bytes > 0.0_wp) problem = problem // ', and ' // &
                bytes_text(rank0_bytes) // ' more on rank 0''s'
            problem = problem // '), and a node has ' // bytes_text(total_min) // ' of memory'
        else if (need > free_min) then
            warning = ': they need at least ' // bytes_text(need) // ' on a node, more than ' // &
                'the ' // bytes_text(free_min) // ' available now'
        end if
    end procedure fit_on_nodes

    !> A memory size: '12.3 GB' (GB = 1024^3 bytes), below 1 GB in MB, below 1 MB in KB.
    function bytes_text(bytes) result(t)
        real(wp), intent(in) :: bytes
        character(len=:), allocatable :: t
        character(len=24) :: buffer
        if (bytes >= 1024.0_wp**3) then
            write(buffer, '(f0.1,a)') bytes / 1024.0_wp**3, ' GB'
        else if (bytes >= 1024.0_wp**2) then
            write(buffer, '(f0.1,a)') bytes / 1024.0_wp**2, ' MB'
        else
            write(buffer, '(f0.1,a)') bytes / 1024.0_wp, ' KB'
        end if
        t = trim(adjustl(buffer))
        if (t(1:1) == '.') t = '0' // t
    end function bytes_text

    !> How the geometry of a checkpoint's stored input differs from `cfg`'s ('' if it
    !> does not): the dimension, the box, the kind of every face, the &body groups and, for a
    !> multi-resolution checkpoint, the &region groups.
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
        text = regions_mismatch()
    contains
        !> A multi-resolution checkpoint's particles have the levels of its own &region groups:
        !> with others, the zones' virtual particles would be made about interfaces where the
        !> levels do not meet (a band moved by 2 coarse spacings ran on, its fine particles
        !> where they were, 8 times the interpolation fallbacks). A uniform checkpoint takes
        !> any regions: they are refined at the restart.
        function regions_mismatch() result(why)
            character(len=:), allocatable :: why
            integer :: r, n_stored, n_input
            character(len=*), parameter :: HOW = ' (a multi-resolution state continues with ' &
                // "the &region groups it was written with, stored in it; to place regions " // &
                'anew, restart a uniform checkpoint with them)'
            why = ''
            n_stored = 0
            n_input = 0
            if (allocated(stored%regions)) n_stored = size(stored%regions)
            if (allocated(cfg%regions)) n_input = size(cfg%regions)
            if (n_stored == 0 .or. n_input == 0) return
            if (n_stored /= n_input) then
                why = 'the checkpoint has ' // trim(int_text(int(n_stored, i8))) // &
                    ' &region group(s) but the input ' // trim(int_text(int(n_input, i8))) // HOW
                return
            end if
            do r = 1, n_input
                associate (a => stored%regions(r), b => cfg%regions(r))
                    if (trim(a%shape) /= trim(b%shape) .or. a%level /= b%level .or. &
                        trim(a%body) /= trim(b%body) .or. &
                        any(abs(a%lo - b%lo) > 1.0e-12_wp * scale) .or. &
                        any(abs(a%hi - b%hi) > 1.0e-12_wp * scale) .or. &
                        abs(a%distance - b%distance) > 1.0e-12_wp * scale) then
                        why = "the checkpoint's &region " // trim(int_text(int(r, i8))) // &
                            " differs from the input's in shape, place, level or distance" // HOW
                        return
                    end if
                end associate
            end do
        end function regions_mismatch
    end procedure geometry_mismatch

    module procedure walls_mismatch
        type(physics_t) :: before, after
        character(len=:), allocatable :: errmsg
        integer :: stat, k, dim
        text = ''
        dim = cfg%domain%dimension
        if (trim(stored%numerics%wall_model) /= trim(cfg%numerics%wall_model)) then
            text = "&numerics wall_model ('" // trim(stored%numerics%wall_model) // "' -> '" // &
                trim(cfg%numerics%wall_model) // "')"
            return
        end if
        call physics_from_config(stored, before, stat, errmsg)
        if (stat == 0) call physics_from_config(cfg, after, stat, errmsg)
        if (stat == 0) then
            if (wall_layers(before) /= wall_layers(after)) then
                text = 'the wall layers (' // int_text(int(wall_layers(before), i8)) // ' -> ' &
                    // int_text(int(wall_layers(after), i8)) // ': &numerics kernel or h_factor)'
                return
            end if
        end if
        if (any(abs(stored%domain%wall_velocity(:, 1:2 * dim) - &
            cfg%domain%wall_velocity(:, 1:2 * dim)) > 0.0_wp)) then
            text = '&domain wall_velocity'
            return
        end if
        do k = 1, min(size(stored%bodies), size(cfg%bodies))
            if (any(abs(stored%bodies(k)%velocity - cfg%bodies(k)%velocity) > 0.0_wp)) then
                text = '&body ' // int_text(int(k, i8)) // " ('" // trim(cfg%bodies(k)%name) // &
                    "') velocity"
                return
            end if
        end do
    end procedure walls_mismatch

    module procedure masses_mismatch
        type(physics_t) :: before, after
        character(len=:), allocatable :: errmsg
        character(len=80) :: line
        real(wp) :: f_stored, f_given
        integer :: stat
        text = ''
        call physics_from_config(stored, before, stat, errmsg)
        if (stat == 0) call physics_from_config(cfg, after, stat, errmsg)
        if (stat /= 0) return
        f_stored = lattice_mass_factor(stored, before)
        f_given = lattice_mass_factor(cfg, after)
        if (abs(f_given / f_stored - 1.0_wp) <= 1.0e-12_wp) return
        write(line, '(a,f8.5,a,f8.5,a)') 'rho0 dx^dim times ', f_stored, ' for its input, ', &
            f_given, ' for this one'
        text = trim(line)
    end procedure masses_mismatch

    module procedure rates_inputs_differ
        character(len=*), parameter :: groups(6) = [character(len=10) :: 'domain', 'fluid', &
            'numerics', 'body', 'refinement', 'region']
        ! &domain dx compared by value: a remeshed checkpoint's stored text keeps the spacing
        ! it was started with, its value (the caller's stored%domain%dx) the one it has now
        ! (compared as text, every restart after an in-run refinement evaluated the rates
        ! anew, and a velocity-Verlet run could not continue bit for bit)
        differ = blocks_of(stored%resolved) /= blocks_of(cfg%resolved) .or. &
            abs(stored%domain%dx - cfg%domain%dx) > 1.0e-12_wp * cfg%domain%dx
    contains
        !> The blocks of those groups in a resolved text ('&name' line to '/' line), in order,
        !> without &domain's dx line.
        function blocks_of(text) result(kept)
            character(len=*), intent(in) :: text
            character(len=:), allocatable :: kept, line
            integer :: start
            logical :: inside, in_domain
            kept = ''
            inside = .false.
            in_domain = .false.
            start = 1
            do while (start <= len(text))
                call next_line(text, start, line)
                if (.not. inside .and. len_trim(line) > 1) then
                    if (line(1:1) == '&') then
                        inside = any(groups == trim(line(2:)))
                        in_domain = trim(line(2:)) == 'domain'
                    end if
                end if
                if (in_domain .and. index(adjustl(line), 'dx =') == 1) cycle
                if (inside) kept = kept // line // new_line('a')
                if (trim(line) == '/') inside = .false.
            end do
        end function blocks_of
    end procedure rates_inputs_differ
end submodule sph_stepper_checks
