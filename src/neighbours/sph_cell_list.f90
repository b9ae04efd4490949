!> Cell (linked) list neighbour search. Particles are binned into cells at least one search
!> radius wide by a counting sort, so a query scans 3^dim cells: O(N) build and search.
!> The list holds, for each query particle i (the owned ones), every other particle j among
!> all n_total (owned + ghosts + mirrors) with |x_i - x_j| < radius: exactly the brute-force set.
module sph_cell_list
    use sph_kinds, only: wp
    implicit none
    private
    public :: neighbour_list_t, build_neighbour_list, brute_force_neighbours, cell_sort_order
    public :: build_cross_list, cell_grid_t, bin_particles, cell_runs, cell_runs_shaped

    !> The binning of one build: kept with the list so a rebuild reuses its storage.
    !> Cell coordinates are taken along the axes in the order `axis`: the axis with the
    !> fewest cells first (fastest in the cell order), the one with the most last. A row of
    !> cells then runs across the domain's short side, so the three to nine rows a query
    !> scans lie a few hundred particles apart in the cell order rather than a whole long side
    !> apart (the pair loop of a 10^6-particle channel stored in that order ran 2-8 % faster).
    type :: cell_grid_t
        integer :: dim = 2
        integer :: axis(3) = [1, 2, 3]         !< physical axis of each cell coordinate
        integer :: ncell(3) = 1                 !< cells along axis(1), axis(2), axis(3)
        real(wp) :: origin(3) = 0.0_wp
        real(wp) :: inv_size = 1.0_wp
        integer, allocatable :: cell_start(:)   !< (ncells + 1)
        integer, allocatable :: sorted(:)       !< particle indices ordered by cell
        integer, allocatable :: cell_of(:)      !< linear cell index of each particle
    end type cell_grid_t

    !> Compressed rows: the neighbours of i are index(start(i) : start(i+1)-1).
    type :: neighbour_list_t
        !> a number no other build of any list has had: what is derived from a list (the
        !> multi-resolution balance's marks) is kept while its generation stays the same
        integer :: generation = 0
        integer :: n_query = 0
        integer :: n_pairs = 0
        integer, allocatable :: start(:)
        integer, allocatable :: index(:)
        !> binning scratch of the last build, one grid per resolution level (0:levels-1)
        type(cell_grid_t), allocatable :: grids(:)
    end type neighbour_list_t

    !> Positions of a grid's binned points in its cell order.
    type :: point_block_t
        real(wp), allocatable :: x(:, :)
    end type point_block_t

    integer, save :: list_builds = 0   !< builds so far, for neighbour_list_t%generation

contains

    !> A new generation for list nl, which has just been (re)built.
    subroutine new_generation(nl)
        type(neighbour_list_t), intent(inout) :: nl
        list_builds = list_builds + 1
        nl%generation = list_builds
    end subroutine new_generation

    !> Neighbours within `radius` of the first n_query particles among the first n_total.
    !> The particles are binned in cells of radius / reach (reach: default 1) and each query
    !> scans the (2 reach + 1)^dim cells around its own, row by row: the cells of a row are
    !> consecutive in the cell order, so a row is one run of `sorted`. Rows and cells are
    !> visited in the cell order (cell_grid_t) and particles within a cell by index, so the
    !> list order is reproducible. reach = 2 scans 6.25 r^2 of candidates in 2D and 15.6 r^3
    !> in 3D instead of 9 r^2 and 27 r^3 (for pi r^2 and 4.2 r^3 of pairs): a quarter less
    !> time in remeshing's lists, 35 % less in a 3D step's search. The time step keeps reach
    !> 1: its pair sums follow the row order, and a chained run continues bit for bit only
    !> while a list rebuilt at a checkpoint orders its rows as the reused one (finer cells
    !> let more particles change cell between rebuilds: jobs_chain_under_stand_in_scheduler
    !> then differed in the last bit).
    !> cell_size (single level only) overrides reach: cells of that size, as many scanned as
    !> the radius needs. A radius far below the spacing (remeshing's thinning: 0.2 old
    !> spacings) would otherwise give cells holding a tenth of a particle, most of the time
    !> going into their counts (10^7 cells for a refinement of 10^5 particles).
    !> Resolution levels (multi-resolution runs): with level (of every particle) and
    !> level_radius(0:), a particle's neighbours are the particles of its own level within
    !> that level's radius; each level is binned in its own grid with its own cell size, so a
    !> fine particle scans fine cells only.
    subroutine build_neighbour_list(x, n_total, n_query, dim, radius, nl, level, level_radius, &
            reach, cell_size)
        real(wp), intent(in) :: x(:, :)
        integer, intent(in) :: n_total, n_query, dim
        real(wp), intent(in) :: radius
        type(neighbour_list_t), intent(inout) :: nl
        integer, intent(in), optional :: level(:)
        real(wp), intent(in), optional :: level_radius(0:)
        integer, intent(in), optional :: reach
        real(wp), intent(in), optional :: cell_size
        integer :: i, j, k, lo(3), hi(3), b, cz, first, last, pairs, lv, n_levels, cells
        real(wp) :: xi(3), d1, d2, d3, size_of_cell
        real(wp), allocatable :: r2max(:)
        integer, allocatable :: members(:)
        type(point_block_t), allocatable :: in_cells(:)   !< per level

        call reserve_rows(nl, n_query, 40)
        cells = 1
        if (present(reach)) cells = reach
        size_of_cell = radius / cells
        if (present(cell_size) .and. .not. present(level)) then
            ! cells of that size, as many scanned as the radius needs
            size_of_cell = cell_size
            cells = max(1, ceiling(radius / cell_size))
        end if

        n_levels = 1
        if (present(level)) n_levels = size(level_radius)
        if (allocated(nl%grids)) then
            if (size(nl%grids) /= n_levels) deallocate(nl%grids)
        end if
        if (.not. allocated(nl%grids)) allocate(nl%grids(0:n_levels - 1))
        allocate(r2max(0:n_levels - 1), in_cells(0:n_levels - 1))
        if (present(level)) then
            do lv = 0, n_levels - 1
                members = pack([(i, i = 1, n_total)], level(1:n_total) == lv)
                call bin_particles(x, size(members), dim, level_radius(lv) / cells, &
                    nl%grids(lv), members)
                call copy_in_cell_order(lv, size(members))
                r2max(lv) = level_radius(lv)**2
            end do
        else
            call bin_particles(x, n_total, dim, size_of_cell, nl%grids(0))
            call copy_in_cell_order(0, n_total)
            r2max(0) = radius * radius
        end if
        pairs = 0
        lv = 0
        do i = 1, n_query
            nl%start(i) = pairs + 1
            if (present(level)) lv = level(i)
            associate (grid => nl%grids(lv), xs => in_cells(lv)%x)
                xi = x(:, i)
                call scan_box(grid, xi, lo, hi, cells)
                do cz = lo(3), hi(3)
                    do b = lo(2), hi(2)
                        call row_run(grid, b, cz, lo, hi, first, last)
                        call make_room(nl, pairs, last - first + 1, i, n_query)
                        do k = first, last
                            j = grid%sorted(k)
                            d1 = xi(1) - xs(1, k)
                            d2 = xi(2) - xs(2, k)
                            d3 = xi(3) - xs(3, k)
                            ! written unconditionally, kept by counting it, with merge: as
                            ! an if, gfortran branched, and in a disordered set (a developed
                            ! flow, a refined one) whether a candidate is within the radius is
                            ! a coin toss (a refinement's list of 4 x 10^5: 150 -> 75 ms)
                            nl%index(pairs + 1) = j
                            pairs = pairs + merge(1, 0, d1**2 + d2**2 + d3**2 < r2max(lv) &
                                .and. j /= i)
                        end do
                    end do
                end do
            end associate
        end do
        nl%start(n_query + 1) = pairs + 1
        nl%n_pairs = pairs
        call new_generation(nl)
    contains
        !> The n_binned positions binned in grid lv, copied in its cell order: a query's
        !> candidates are then read in runs, not gathered one by one (a refinement's list of
        !> 4 x 10^5 particles took a quarter of the time after the new positions).
        subroutine copy_in_cell_order(lv_binned, n_binned)
            integer, intent(in) :: lv_binned, n_binned
            integer :: q
            allocate(in_cells(lv_binned)%x(3, max(n_binned, 1)))
            do q = 1, n_binned
                in_cells(lv_binned)%x(:, q) = x(:, nl%grids(lv_binned)%sorted(q))
            end do
        end subroutine copy_in_cell_order
    end subroutine build_neighbour_list

    !> Neighbours of query points among a separate set of candidates (remeshing's transfers:
    !> old to new particles, sources to virtual particles): for each of the n_query points xq,
    !> every candidate xc(:, k), k <= n_cand, with |xq - xc| < half_width on EVERY axis (a
    !> cube: the support of a tensor-product kernel), index holding candidate indices. Only the
    !> candidates are binned, in cells of half_width: a query scans 3^dim cells and never
    !> sees the other queries. Order as in build_neighbour_list (reproducible).
    subroutine build_cross_list(xq, n_query, xc, n_cand, dim, half_width, nl)
        real(wp), intent(in) :: xq(:, :), xc(:, :)
        integer, intent(in) :: n_query, n_cand, dim
        real(wp), intent(in) :: half_width
        type(neighbour_list_t), intent(inout) :: nl
        integer :: i, j, k, lo(3), hi(3), b, cz, first, last, pairs
        real(wp) :: xi(3), d(3)

        call reserve_rows(nl, n_query, 16)
        if (allocated(nl%grids)) then
            if (size(nl%grids) /= 1) deallocate(nl%grids)
        end if
        if (.not. allocated(nl%grids)) allocate(nl%grids(0:0))
        call bin_particles(xc, n_cand, dim, half_width, nl%grids(0))
        pairs = 0
        associate (grid => nl%grids(0))
            do i = 1, n_query
                nl%start(i) = pairs + 1
                xi = 0.0_wp
                xi(1:dim) = xq(1:dim, i)
                call scan_box(grid, xi, lo, hi)
                do cz = lo(3), hi(3)
                    do b = lo(2), hi(2)
                        call row_run(grid, b, cz, lo, hi, first, last)
                        call make_room(nl, pairs, last - first + 1, i, n_query)
                        do k = first, last
                            j = grid%sorted(k)
                            d = 0.0_wp
                            d(1:dim) = abs(xi(1:dim) - xc(1:dim, j))
                            nl%index(pairs + 1) = j
                            pairs = pairs + merge(1, 0, max(d(1), d(2), d(3)) < half_width)
                        end do
                    end do
                end do
            end do
        end associate
        nl%start(n_query + 1) = pairs + 1
        nl%n_pairs = pairs
        call new_generation(nl)
    end subroutine build_cross_list

    !> The binned points in the cells within `reach` cells of xi, as runs of the cell order:
    !> grid%sorted(first(r):last(r)), r = 1..n_runs, one run per row of cells, in the order
    !> of build_cross_list's rows. A caller that keeps its points' data in the cell order
    !> (copied once after bin_particles) then reads each run contiguously. first and last
    !> need room for (2 reach + 1)^(dim - 1) runs.
    pure subroutine cell_runs(grid, xi, reach, first, last, n_runs)
        type(cell_grid_t), intent(in) :: grid
        real(wp), intent(in) :: xi(3)
        integer, intent(in) :: reach
        integer, intent(out) :: first(:), last(:), n_runs
        integer :: lo(3), hi(3), b, cz, f, l
        n_runs = 0
        call scan_box(grid, xi, lo, hi, reach)
        do cz = lo(3), hi(3)
            do b = lo(2), hi(2)
                call row_run(grid, b, cz, lo, hi, f, l)
                if (l < f) cycle
                n_runs = n_runs + 1
                first(n_runs) = f
                last(n_runs) = l
            end do
        end do
    end subroutine cell_runs

    !> As cell_runs in 2D, each row of cells cut to row_reach(k) cells either side of xi's,
    !> k its offset in rows (0 .. ubound(row_reach)), a row with a negative reach skipped: a
    !> shape narrower than the square (sph_coarsen's rows and conflicts, a cross and a disc,
    !> a quarter of the square's cells fewer). The runs come in cell_runs' order.
    pure subroutine cell_runs_shaped(grid, xi, row_reach, first, last, n_runs)
        type(cell_grid_t), intent(in) :: grid
        real(wp), intent(in) :: xi(3)
        integer, intent(in) :: row_reach(0:)
        integer, intent(out) :: first(:), last(:), n_runs
        integer :: c(3), lo(3), hi(3), b, k, f, l, reach
        reach = ubound(row_reach, 1)
        c = cell_coords(grid, xi)
        lo = 1
        hi = 1
        n_runs = 0
        do b = max(c(2) - reach, 1), min(c(2) + reach, grid%ncell(2))
            k = abs(b - c(2))
            if (row_reach(k) < 0) cycle
            lo(1) = max(c(1) - row_reach(k), 1)
            hi(1) = min(c(1) + row_reach(k), grid%ncell(1))
            call row_run(grid, b, 1, lo, hi, f, l)
            if (l < f) cycle
            n_runs = n_runs + 1
            first(n_runs) = f
            last(n_runs) = l
        end do
    end subroutine cell_runs_shaped

    !> Room for the rows of n_query queries (an initial guess of per_query pairs each).
    subroutine reserve_rows(nl, n_query, per_query)
        type(neighbour_list_t), intent(inout) :: nl
        integer, intent(in) :: n_query, per_query
        nl%n_query = n_query
        if (allocated(nl%start)) then
            if (size(nl%start) < n_query + 1) deallocate(nl%start)
        end if
        if (.not. allocated(nl%start)) allocate(nl%start(max(n_query + 1, 1)))
        if (.not. allocated(nl%index)) allocate(nl%index(max(64, per_query * n_query)))
    end subroutine reserve_rows

    !> The cells a query at xi scans: its own and `reach` (default 1) more on each side
    !> along each axis, lo:hi.
    pure subroutine scan_box(grid, xi, lo, hi, reach)
        type(cell_grid_t), intent(in) :: grid
        real(wp), intent(in) :: xi(3)
        integer, intent(out) :: lo(3), hi(3)
        integer, intent(in), optional :: reach
        integer :: c(3), r
        r = 1
        if (present(reach)) r = reach
        c = cell_coords(grid, xi)
        lo = 1; hi = 1
        lo(1:grid%dim) = max(c(1:grid%dim) - r, 1)
        hi(1:grid%dim) = min(c(1:grid%dim) + r, grid%ncell(1:grid%dim))
    end subroutine scan_box

    !> The cells lo(1):hi(1) of row (b, cz) are consecutive: one run first:last of sorted.
    pure subroutine row_run(grid, b, cz, lo, hi, first, last)
        type(cell_grid_t), intent(in) :: grid
        integer, intent(in) :: b, cz, lo(3), hi(3)
        integer, intent(out) :: first, last
        integer :: row
        row = grid%ncell(1) * ((b - 1) + grid%ncell(2) * (cz - 1))
        first = grid%cell_start(row + lo(1))
        last = grid%cell_start(row + hi(1) + 1) - 1
    end subroutine row_run

    !> index has room for `run` more candidates after `pairs` (plus the one written ahead).
    subroutine make_room(nl, pairs, run, i, n_query)
        type(neighbour_list_t), intent(inout) :: nl
        integer, intent(in) :: pairs, run, i, n_query
        if (pairs + run + 1 > size(nl%index)) call grow(nl%index, &
            max(pairs + run + 1, projected_pairs(pairs, i, n_query)))
    end subroutine make_room

    !> array holds `needed` entries, the first ones kept.
    subroutine grow(array, needed)
        integer, allocatable, intent(inout) :: array(:)
        integer, intent(in) :: needed
        integer, allocatable :: bigger(:)
        allocate(bigger(needed))
        bigger(1:size(array)) = array
        call move_alloc(bigger, array)
    end subroutine grow

    !> Room for all rows, projected from the `pairs` of the rows before query i, plus 10 %.
    pure integer function projected_pairs(pairs, i, n_query)
        integer, intent(in) :: pairs, i, n_query
        projected_pairs = int(min(1.1_wp * real(pairs, wp) / max(i - 1, 1) * n_query + 64.0_wp, &
            real(huge(1), wp)))
    end function projected_pairs

    !> Stable counting sort of particles into cells of at least `cell_size` covering their
    !> bounding box (also for cell_runs). The grid's arrays are reused when they are
    !> large enough. With members, only the particles members(1:n) are binned (sorted holds
    !> their indices into x).
    subroutine bin_particles(x, n, dim, cell_size, grid, members)
        real(wp), intent(in) :: x(:, :)
        integer, intent(in) :: n, dim
        real(wp), intent(in) :: cell_size
        type(cell_grid_t), intent(inout) :: grid
        integer, intent(in), optional :: members(:)
        real(wp) :: lo(3), hi(3), size_used
        integer :: i, k, ncells, cell, span(3)
        integer(8) :: estimate

        grid%dim = dim
        lo = 0.0_wp; hi = 0.0_wp
        if (n > 0) then
            lo = x(:, member(1)); hi = lo
            do k = 2, n
                i = member(k)
                lo = min(lo, x(:, i))
                hi = max(hi, x(:, i))
            end do
        end if
        ! a stray far-away particle must not make the grid huge: cap cells at ~4 per particle
        size_used = cell_size
        do
            span = 1
            span(1:dim) = max(1, int((hi(1:dim) - lo(1:dim)) / size_used) + 1)
            estimate = product(int(span, 8))
            if (estimate <= 4_8 * n + 64_8) exit
            size_used = size_used * 1.5_wp
        end do
        ! the axes by their number of cells, fewest first (a stable sort: ties keep x, y, z)
        grid%axis = [1, 2, 3]
        do i = 2, dim
            k = i
            do while (k > 1)
                if (span(grid%axis(k - 1)) <= span(grid%axis(k))) exit
                grid%axis(k - 1:k) = grid%axis([k, k - 1])
                k = k - 1
            end do
        end do
        grid%ncell = span(grid%axis)
        grid%origin = lo
        grid%inv_size = 1.0_wp / size_used
        ncells = int(estimate)
        call reserve(grid%cell_start, ncells + 1)
        call reserve(grid%sorted, n)
        call reserve(grid%cell_of, n)
        grid%cell_start(1:ncells + 1) = 0
        do k = 1, n
            cell = linear_cell(grid, cell_coords(grid, x(:, member(k))))
            grid%cell_of(k) = cell
            grid%cell_start(cell + 1) = grid%cell_start(cell + 1) + 1
        end do
        ! cell_start(c) is the first slot of cell c; it serves as c's fill cursor, which
        ! ends at the first slot of c + 1, and is then shifted back by one cell
        grid%cell_start(1) = 1
        do cell = 1, ncells
            grid%cell_start(cell + 1) = grid%cell_start(cell + 1) + grid%cell_start(cell)
        end do
        do k = 1, n
            cell = grid%cell_of(k)
            grid%sorted(grid%cell_start(cell)) = member(k)
            grid%cell_start(cell) = grid%cell_start(cell) + 1
        end do
        grid%cell_start(2:ncells + 1) = grid%cell_start(1:ncells)
        grid%cell_start(1) = 1
    contains
        pure integer function member(kk)
            integer, intent(in) :: kk
            member = kk
            if (present(members)) member = members(kk)
        end function member
    end subroutine bin_particles

    !> array holds at least n entries (contents not kept when it grows).
    subroutine reserve(array, n)
        integer, allocatable, intent(inout) :: array(:)
        integer, intent(in) :: n
        if (allocated(array)) then
            if (size(array) >= max(n, 1)) return
            deallocate(array)
        end if
        allocate(array(max(n, 1)))
    end subroutine reserve

    !> Cell coordinates of xi along grid%axis(1:dim) (see cell_grid_t).
    pure function cell_coords(grid, xi) result(c)
        type(cell_grid_t), intent(in) :: grid
        real(wp), intent(in) :: xi(3)
        integer :: c(3), k, a
        c = 1
        do k = 1, grid%dim
            a = grid%axis(k)
            c(k) = int((xi(a) - grid%origin(a)) * grid%inv_size) + 1
            c(k) = min(max(c(k), 1), grid%ncell(k))
        end do
    end function cell_coords

    pure integer function linear_cell(grid, c)
        type(cell_grid_t), intent(in) :: grid
        integer, intent(in) :: c(3)
        linear_cell = c(1) + grid%ncell(1) * ((c(2) - 1) + grid%ncell(2) * (c(3) - 1))
    end function linear_cell

    !> Order of the first n particles by cell (then by index): used to store owned particles
    !> cell by cell, so a neighbour loop walks memory nearly in order.
    subroutine cell_sort_order(x, n, dim, cell_size, order)
        real(wp), intent(in) :: x(:, :)
        integer, intent(in) :: n, dim
        real(wp), intent(in) :: cell_size
        integer, intent(out) :: order(:)
        type(cell_grid_t) :: grid
        call bin_particles(x, n, dim, cell_size, grid)
        order(1:n) = grid%sorted(1:n)
    end subroutine cell_sort_order

    !> Reference O(N^2) search with the same criterion, for tests.
    subroutine brute_force_neighbours(x, n_total, n_query, radius, nl)
        real(wp), intent(in) :: x(:, :)
        integer, intent(in) :: n_total, n_query
        real(wp), intent(in) :: radius
        type(neighbour_list_t), intent(out) :: nl
        integer :: i, j, pairs
        real(wp) :: d(3)
        allocate(nl%start(n_query + 1), nl%index(max(64, n_query * n_total)))
        pairs = 0
        do i = 1, n_query
            nl%start(i) = pairs + 1
            do j = 1, n_total
                if (j == i) cycle
                d = x(:, i) - x(:, j)
                if (d(1)**2 + d(2)**2 + d(3)**2 < radius * radius) then
                    pairs = pairs + 1
                    nl%index(pairs) = j
                end if
            end do
        end do
        nl%start(n_query + 1) = pairs + 1
        nl%n_query = n_query
        nl%n_pairs = pairs
        call new_generation(nl)
    end subroutine brute_force_neighbours
end module sph_cell_list
