!> The process's own memory accounting: its peak resident set, as the kernel counts it
!> (Linux /proc/self/status, VmHWM). Elsewhere the figure is unknown and reported as such.
!> node_memory_bytes: the node's memory, total and available now (/proc/meminfo).
!> And keep_freed_memory: asks the C library to keep every freed block mapped for
!> reuse instead of returning them to the system (sph_memory_reuse.c), so a remesh or a list
!> rebuild reuses pages already touched instead of faulting in fresh ones. Call once, early;
!> where the library offers no such setting nothing changes.
module sph_memory
    use sph_kinds, only: i8
    implicit none
    private
    public :: peak_resident_bytes, keep_freed_memory, node_memory_bytes

    interface
        !> sph_memory_reuse.c
        subroutine keep_freed_memory() bind(C, name='sph_keep_freed_memory')
        end subroutine keep_freed_memory
    end interface

contains

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

    !> The node's memory in bytes, in all (MemTotal) and available to new work without
    !> swapping (MemAvailable); -1 for a figure the system does not give.
    subroutine node_memory_bytes(total, available)
        integer(i8), intent(out) :: total, available
        integer :: unit, stat
        character(len=256) :: line
        total = -1_i8
        available = -1_i8
        open(newunit=unit, file='/proc/meminfo', action='read', status='old', iostat=stat)
        if (stat /= 0) return
        do
            read(unit, '(a)', iostat=stat) line
            if (stat /= 0) exit
            if (line(1:9) == 'MemTotal:') total = kilobytes_of(line(10:))
            if (line(1:13) == 'MemAvailable:') available = kilobytes_of(line(14:))
        end do
        close(unit)
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
end module sph_memory
