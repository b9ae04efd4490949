!> Lines of a text held in one string (a stored input, a file read whole), one at a time.
module sph_text_lines
    implicit none
    private
    public :: next_line

contains

    !> The line of `text` that starts at `start` (without its newline) and, in start, where
    !> the next one starts; a last line without a newline is a line too. Callers loop while
    !> start <= len(text).
    subroutine next_line(text, start, line)
        character(len=*), intent(in) :: text
        integer, intent(inout) :: start
        character(len=:), allocatable, intent(out) :: line
        integer :: stop_at
        stop_at = index(text(start:), new_line('a'))
        if (stop_at == 0) stop_at = len(text) - start + 2
        line = text(start:start + stop_at - 2)
        start = start + stop_at
    end subroutine next_line
end module sph_text_lines
