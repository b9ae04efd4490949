!> The process's own memory accounting: its peak resident set, as the kernel counts it
!> (Linux /proc/self/status, VmHWM). Elsewhere the figure is unknown and reported as such.
!> node_memory_bytes: the node's memory, total and available now (/proc/meminfo), within the
!> process's control group limit or SPHREMESH_NODE_MEMORY.
!> And keep_freed_memory: asks the C library to keep every freed block mapped for
!> reuse instead of returning them to the system (sph_memory_reuse.c), so a remesh or a list
!> rebuild reuses pages already touched instead of faulting in fresh ones. Call once, early;
!> where the library offers no such setting nothing changes.
module sph_memory
    use sph_kinds, only: i8
    implicit none
    private
    public :: peak_resident_bytes, keep_freed_memory, node_memory_bytes
    public :: note_startup_memory, startup_memory_bytes

    !> the process's peak at note_startup_memory (its libraries and MPI, no particle yet);
    !> -1 until noted or where the system does not say
    integer(i8), save :: startup_bytes = -1_i8

    interface
        !> sph_memory_reuse.c
        subroutine keep_freed_memory() bind(C, name='sph_keep_freed_memory')
        end subroutine keep_freed_memory
    end interface

contains

    !> Note the memory the process holds before any particle (call once MPI is started):
    !> the libraries' share, which does not grow with the particles (about 19 MB a rank with
    !> Debian's Open MPI and HDF5; more with some interconnects' MPI).
    subroutine note_startup_memory()
        startup_bytes = peak_resident_bytes()
    end subroutine note_startup_memory

    !> What note_startup_memory found (-1: not noted, or unknown).
    integer(i8) function startup_memory_bytes()
        startup_memory_bytes = startup_bytes
    end function startup_memory_bytes

    !> Peak resident set size of this process in bytes; -1 when the system does not say.
    function peak_resident_bytes() result(bytes)
        integer(i8) :: bytes
        integer :: unit, stat, k
        integer(i8) :: kilobytes
        character(len=256) :: line
        bytes = -1_i8
        open(newunit=unit, file='/proc/self/status', action='read', status='old', iostat=stat)
        if (stat /= 0) return
        do
            read(unit, '(a)', iostat=stat) line
            if (stat /= 0) exit
            if (line(1:6) /= 'VmHWM:') cycle
            k = index(line, 'kB')
            if (k == 0) exit
            read(line(7:k - 1), *, iostat=stat) kilobytes
            if (stat == 0) bytes = 1024_i8 * kilobytes
            exit
        end do
        close(unit)
    end function peak_resident_bytes

    !> The memory this process's node gives the run, in bytes: in all and available to new
    !> work without swapping; -1 for a figure the system does not give. In all: the node's
    !> (/proc/meminfo MemTotal), or less when the process's control group is limited (a batch
    !> system's memory request: SLURM's --mem, a container's limit; cgroup_limit_bytes), or
    !> the environment variable SPHREMESH_NODE_MEMORY (bytes, or with a suffix K, M, G or T,
    !> powers of 1024) for a limit the code cannot see. Available: MemAvailable, at most the
    !> total. errmsg (optional): not empty when SPHREMESH_NODE_MEMORY is set but not such a
    !> size (it is then ignored here; the set-up refuses it).
    subroutine node_memory_bytes(total, available, errmsg)
        integer(i8), intent(out) :: total, available
        character(len=:), allocatable, intent(out), optional :: errmsg
        integer :: unit, stat, length
        integer(i8) :: limit
        character(len=256) :: line
        character(len=64) :: given
        total = -1_i8
        available = -1_i8
        if (present(errmsg)) errmsg = ''
        open(newunit=unit, file='/proc/meminfo', action='read', status='old', iostat=stat)
        if (stat == 0) then
            do
                read(unit, '(a)', iostat=stat) line
                if (stat /= 0) exit
                if (line(1:9) == 'MemTotal:') total = kilobytes_of(line(10:))
                if (line(1:13) == 'MemAvailable:') available = kilobytes_of(line(14:))
            end do
            close(unit)
        end if
        limit = cgroup_limit_bytes()
        if (limit > 0 .and. (total < 0 .or. limit < total)) total = limit
        call get_environment_variable('SPHREMESH_NODE_MEMORY', given, length, stat)
        if (stat == 0 .and. length > 0) then
            limit = size_in_bytes(given)
            if (limit > 0) then
                total = limit
            else if (present(errmsg)) then
                errmsg = "SPHREMESH_NODE_MEMORY = '" // trim(given) // "' is not a size in " // &
                    'bytes (a whole number > 0, optionally with K, M, G or T: 64G)'
            end if
        end if
        if (total > 0 .and. available > total) available = total
    contains
        !> "   24576000 kB" in bytes (-1 when unreadable).
        integer(i8) function kilobytes_of(text)
            character(len=*), intent(in) :: text
            integer :: k, st
            integer(i8) :: kb
            kilobytes_of = -1_i8
            k = index(text, 'kB')
            if (k == 0) return
            read(text(1:k - 1), *, iostat=st) kb
            if (st == 0) kilobytes_of = 1024_i8 * kb
        end function kilobytes_of
    end subroutine node_memory_bytes

    !> '64G', '512M', '1000000' in bytes (K, M, G, T: powers of 1024); -1 when not such a size.
    integer(i8) function size_in_bytes(text) result(bytes)
        character(len=*), intent(in) :: text
        character(len=*), parameter :: SUFFIXES = 'KMGT'
        character(len=:), allocatable :: digits
        integer :: power, st
        integer(i8) :: number
        bytes = -1_i8
        digits = trim(adjustl(text))
        if (len(digits) == 0) return
        power = index(SUFFIXES, digits(len(digits):len(digits)))
        if (power == 0) power = index('kmgt', digits(len(digits):len(digits)))
        if (power > 0) digits = digits(1:len(digits) - 1)
        if (len(digits) == 0 .or. len(digits) > 15) return
        if (verify(digits, '0123456789') /= 0) return
        read(digits, *, iostat=st) number
        if (st /= 0 .or. number <= 0) return
        bytes = number * 1024_i8**power
    end function size_in_bytes

    !> The smallest memory limit of this process's control group and its ancestors (Linux
    !> cgroup v2 memory.max, v1 memory.limit_in_bytes; a batch system puts a job's request
    !> there), in bytes; -1 when there is none (or no cgroup file can be read: not Linux, or
    !> a container that hides them). v1's "no limit" is a value near 2^63.
    integer(i8) function cgroup_limit_bytes() result(limit)
        integer :: unit, stat, first, second
        character(len=1024) :: line
        character(len=:), allocatable :: v1_path, v2_path
        limit = -1_i8
        open(newunit=unit, file='/proc/self/cgroup', action='read', status='old', iostat=stat)
        if (stat /= 0) return
        do
            read(unit, '(a)', iostat=stat) line
            if (stat /= 0) exit
            ! hierarchy-id:controller-list:path
            first = index(line, ':')
            if (first == 0) cycle
            second = first + index(line(first + 1:), ':')
            if (second == first) cycle
            if (line(1:second) == '0::') then
                v2_path = trim(line(second + 1:))
            else if (index(',' // line(first + 1:second - 1) // ',', ',memory,') > 0) then
                v1_path = trim(line(second + 1:))
            end if
        end do
        close(unit)
        if (allocated(v1_path)) call walk('/sys/fs/cgroup/memory', v1_path, &
            'memory.limit_in_bytes')
        if (allocated(v2_path)) call walk('/sys/fs/cgroup', v2_path, 'memory.max')
    contains
        !> limit lowered to every finite limit in file_name of path and its ancestors
        subroutine walk(root, path, file_name)
            character(len=*), intent(in) :: root, path, file_name
            character(len=:), allocatable :: dir
            integer(i8) :: value
            integer :: cut
            dir = path
            do
                value = limit_in(root // dir // '/' // file_name)
                if (value > 0 .and. value < 2_i8**60) then
                    if (limit < 0 .or. value < limit) limit = value
                end if
                cut = index(dir, '/', back=.true.)
                if (cut <= 1 .and. len(dir) <= 1) exit
                dir = dir(1:max(cut - 1, 0))
                if (len(dir) == 0) dir = '/'
            end do
        end subroutine walk

        !> The number in a limit file; -1 for 'max', a missing file or anything else.
        integer(i8) function limit_in(file_path) result(value)
            character(len=*), intent(in) :: file_path
            integer :: u, st
            character(len=64) :: text
            value = -1_i8
            open(newunit=u, file=file_path, action='read', status='old', iostat=st)
            if (st /= 0) return
            read(u, '(a)', iostat=st) text
            close(u)
            if (st /= 0) return
            if (verify(trim(text), '0123456789') /= 0 .or. len_trim(text) == 0) return
            read(text, *, iostat=st) value
            if (st /= 0) value = -1_i8
        end function limit_in
    end function cgroup_limit_bytes
end module sph_memory
