!> The process's own memory accounting: its peak resident set, as the kernel counts it
!> (Linux /proc/self/status, VmHWM). Elsewhere the figure is unknown and reported as such.
!> And keep_freed_memory: asks the C library to keep every freed block mapped for
!> reuse instead of returning them to the system (sph_memory_reuse.c), so a remesh or a list
!> rebuild reuses pages already touched instead of faulting in fresh ones. Call once, early;
!> where the library offers no such setting nothing changes.
module sph_memory
    use sph_kinds, only: i8
    implicit none
    private
    public :: peak_resident_bytes, keep_freed_memory

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
end module sph_memory
