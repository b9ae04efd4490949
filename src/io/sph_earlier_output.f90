!> Output of an earlier run set aside before a run would overwrite it. A run writes its files
!> under fixed names (`<case>_<step>.h5`, `<case>_checkpoint_<step>.h5`, `<case>.xdmf`, ...):
!> started again into the same `output_dir`, or continued from a checkpoint older than the
!> newest files there, it would replace an earlier run's results without a word (a second run
!> of the same input replaced every snapshot and checkpoint of the first). So before its first
!> output a run moves the files it could overwrite into a new folder
!> `<output_dir>/<case>_earlier_<N>` (N the first free number), all together, so that the
!> moved `.xdmf` still opens the moved snapshots (it names them without a folder), and says
!> so in the log:
!>  - a fresh run: every file of its case (snapshots, checkpoints, failure snapshots, the
!>    `.xdmf` and the forces file);
!>  - a restart at step S: the snapshots, checkpoints and failure snapshots of steps after S,
!>    the forces file when it has rows after S (the restart continues it from its rows up
!>    to S) and a copy of the `.xdmf` (the restart writes its own from the checkpoint), with
!>    the snapshots of steps up to S, left where they were, linked beside it (hard links).
!> A run continued from the newest checkpoint of a run that stopped there (a job chain) has
!> nothing to set aside. Files of other cases and `.tmp` leftovers are not touched.
module sph_earlier_output
    use sph_kinds, only: i8
    use sph_mpi_env, only: mpi_env_t, broadcast_text
    use sph_filesystem, only: list_directory, make_directories, rename_file, link_file, &
        write_text_file_whole, text_buffer_t, remove_empty_directory, delete_file
    use sph_text_lines, only: next_line
    implicit none
    private
    public :: set_aside_earlier_output, earlier_file_step, FILE_NOT_OURS, FILE_NO_STEP

    !> earlier_file_step's results for a name that is not one of the case's files, and for
    !> one of them without a step (the `.xdmf`, the forces file)
    integer(i8), parameter :: FILE_NOT_OURS = -2_i8
    integer(i8), parameter :: FILE_NO_STEP = -1_i8
    !> the folders `<case>_earlier_1` ... tried before giving up
    integer, parameter :: MAX_EARLIER = 9999

contains

    !> The step of `name` when it is one of the files a run of `case_name` writes:
    !> `<case>_<step>.h5`, `<case>_checkpoint_<step>.h5`, `<case>_failure_<step>.h5` (the
    !> step: decimal digits only); FILE_NO_STEP for `<case>.xdmf` and `<case>_forces.csv`;
    !> FILE_NOT_OURS for anything else (another case's files, `.tmp` leftovers, folders).
    pure integer(i8) function earlier_file_step(name, case_name) result(step)
        character(len=*), intent(in) :: name, case_name
        character(len=*), parameter :: MIDDLES(3) = [character(len=12) :: '', 'checkpoint_', &
            'failure_']
        character(len=:), allocatable :: prefix, digits
        integer :: k, n
        step = FILE_NOT_OURS
        if (name == case_name // '.xdmf' .or. name == case_name // '_forces.csv') then
            step = FILE_NO_STEP
            return
        end if
        n = len(name)
        if (n < 4) return
        if (name(n - 2:) /= '.h5') return
        do k = 1, size(MIDDLES)
            prefix = case_name // '_' // trim(MIDDLES(k))
            if (n <= len(prefix) + 3) cycle
            if (name(1:len(prefix)) /= prefix) cycle
            digits = name(len(prefix) + 1:n - 3)
            ! (at most 18 digits: an integer(i8) holds them)
            if (len(digits) > 18 .or. verify(digits, '0123456789') /= 0) cycle
            step = digits_value(digits)
            return
        end do
    end function earlier_file_step

    pure integer(i8) function digits_value(digits) result(v)
        character(len=*), intent(in) :: digits
        integer :: k
        v = 0
        do k = 1, len(digits)
            v = 10 * v + (iachar(digits(k:k)) - iachar('0'))
        end do
    end function digits_value

    !> Move the files of `case_name` in `directory` that this run could overwrite into a new
    !> folder `<directory>/<case>_earlier_<N>` (module header): after_step < 0 for a fresh
    !> run (all of them), else the step the run continues from (the stepped files after it).
    !> Collective; rank 0 moves. moved: how many files (0: nothing there, or no directory
    !> yet); folder: where they went. stat /= 0 with errmsg when a file could not be moved
    !> (then the ones moved before it are moved back, so that the earlier run's files stay
    !> together, and nothing was overwritten).
    !> rows_dropped (a restart): rows of the forces file cut short (a crash or a full disk
    !> of an earlier run) that were dropped from it, when no row of a later step sent the
    !> file aside (with them in it).
    subroutine set_aside_earlier_output(env, directory, case_name, after_step, moved, folder, &
            stat, errmsg, rows_dropped)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: directory, case_name
        integer(i8), intent(in) :: after_step
        integer, intent(out) :: moved, stat
        character(len=:), allocatable, intent(out) :: folder, errmsg
        integer, intent(out), optional :: rows_dropped
        character(len=:), allocatable :: listing, name, result_text
        character(len=32) :: number
        !> the names moved so far, one per line (moved back when a later one cannot move)
        type(text_buffer_t) :: moved_names
        !> whether this call made `folder` (only then may it go again)
        logical :: made_folder
        integer :: dropped
        integer :: start, k, list_stat, n
        integer(i8) :: step
        logical :: exists

        moved = 0
        stat = 0
        folder = ''
        errmsg = ''
        result_text = ''
        made_folder = .false.
        dropped = 0
        if (env%rank == 0) then
            call list_directory(directory, listing, list_stat)
            ! (a directory that cannot be listed does not exist yet: the output makes it)
            if (list_stat /= 0) listing = ''
            start = 1
            do k = 1, len(listing)
                if (listing(k:k) /= new_line('a')) cycle
                name = listing(start:k - 1)
                start = k + 1
                step = earlier_file_step(name, case_name)
                if (step == FILE_NOT_OURS) cycle
                if (after_step >= 0 .and. step <= after_step) cycle
                if (moved == 0) then
                    call new_folder(folder, stat)
                    if (stat /= 0) then
                        errmsg = "cannot make a folder '" // directory // '/' // case_name // &
                            "_earlier_N' for the earlier output there"
                        exit
                    end if
                end if
                call rename_file(directory // '/' // name, folder // '/' // name, stat)
                if (stat /= 0) then
                    errmsg = "cannot move '" // directory // '/' // name // "' to '" // &
                        folder // "'"
                    call move_back()
                    exit
                end if
                call moved_names%put(name // new_line('a'))
                moved = moved + 1
            end do
            ! a restart continues the forces file and the index: the earlier continuation's
            ! rows after its step go with its files (the forces file kept them, and its times
            ! ran backwards), and the index of those files is kept beside them
            if (stat == 0 .and. after_step >= 0) call split_continued_files()
            ! (to the other ranks as lines: the counts, the folder, the message)
            write(number, '(i0, 1x, i0, 1x, i0)') stat, moved, dropped
            result_text = trim(number) // new_line('a') // folder // new_line('a') // errmsg
        end if
        call broadcast_text(env, result_text)
        n = index(result_text, new_line('a'))
        read(result_text(1:n - 1), *) stat, moved, dropped
        if (present(rows_dropped)) rows_dropped = dropped
        result_text = result_text(n + 1:)
        n = index(result_text, new_line('a'))
        folder = result_text(1:n - 1)
        errmsg = result_text(n + 1:)

    contains

        !> Rank 0: the files moved so far back where they were (a move that stopped half-way
        !> split the earlier run over two folders, its .xdmf in one and some of its
        !> snapshots in the other); errmsg says whether they all went back.
        subroutine move_back()
            character(len=:), allocatable :: back
            integer :: at, back_stat, failed
            failed = 0
            at = 1
            do while (at <= moved_names%used)
                call next_line(moved_names%text(1:moved_names%used), at, back)
                call rename_file(folder // '/' // back, directory // '/' // back, back_stat)
                if (back_stat /= 0) failed = failed + 1
            end do
            if (failed == 0) then
                if (moved > 0) errmsg = errmsg // ' (the files moved before it are back ' // &
                    'in place)'
                if (made_folder) call remove_empty_directory(folder)
            else
                write(number, '(i0)') failed
                errmsg = errmsg // ' (' // trim(number) // " of the files moved before it " // &
                    "could not be moved back: they are in '" // folder // "')"
            end if
            moved = 0
        end subroutine move_back

        !> Rank 0, a restart: when `<case>_forces.csv` has rows of steps after after_step, it
        !> goes whole into the folder and its rows up to after_step (and the header) are
        !> written back in its place; when files were set aside, a copy of `<case>.xdmf` goes
        !> with them.
        subroutine split_continued_files()
            character(len=:), allocatable :: text, kept, line, path, reason
            integer :: start, comma, second, read_stat, header_commas
            integer(i8) :: row_step
            logical :: later
            integer :: cut
            path = directory // '/' // case_name // '_forces.csv'
            call read_whole(path, text, read_stat)
            if (read_stat == 0) then
                kept = ''
                later = .false.
                cut = 0
                start = 1
                do while (start <= len(text))
                    call next_line(text, start, line)
                    ! (a row: time, step, ...; the header's second field is not a number)
                    comma = index(line, ',')
                    second = index(line(comma + 1:), ',')
                    row_step = -1
                    if (comma > 0 .and. second > 1) then
                        read(line(comma + 1:comma + second - 1), *, iostat=read_stat) row_step
                        if (read_stat /= 0) row_step = -1
                    end if
                    ! (a row cut short by a full disk or a crash, its fields fewer than the
                    ! header's, goes with the later rows: kept, it sat among them as a
                    ! malformed row, its step perhaps a prefix of the real one)
                    if (len(kept) == 0) header_commas = count_commas(line)
                    if (row_step > after_step) then
                        later = .true.
                    else if (len(kept) > 0 .and. count_commas(line) /= header_commas) then
                        cut = cut + 1
                    else
                        kept = kept // line // new_line('a')
                    end if
                end do
                ! rows cut short alone (no later step: nothing to set aside) are dropped in
                ! place (set aside, they made a folder and a warning of later steps that
                ! were not there)
                if (.not. later .and. cut > 0) then
                    reason = ''
                    call write_text_file_whole(path, kept, stat, reason)
                    if (stat /= 0) then
                        errmsg = "cannot drop the rows cut short of '" // path // "': " // reason
                        return
                    end if
                    dropped = cut
                end if
                if (later) then
                    if (moved == 0) call new_folder(folder, stat)
                    if (stat == 0) call rename_file(path, folder // '/' // case_name // &
                        '_forces.csv', stat)
                    if (stat == 0) then
                        call moved_names%put(case_name // '_forces.csv' // new_line('a'))
                        moved = moved + 1
                    end if
                    reason = ''
                    if (stat == 0) call write_text_file_whole(path, kept, stat, reason)
                    if (stat /= 0) then
                        write(number, '(i0)') after_step
                        errmsg = 'cannot set the rows after step ' // trim(number) // " of '" &
                            // path // "' aside"
                        if (len(reason) > 0) errmsg = errmsg // ': ' // reason
                        call move_back()
                        return
                    end if
                end if
            end if
            if (moved == 0) return
            call read_whole(directory // '/' // case_name // '.xdmf', text, read_stat)
            if (read_stat == 0) call write_series_copy(text, folder // '/' // case_name // &
                '.xdmf', stat)
            if (stat /= 0) call move_back()
        end subroutine split_continued_files

        pure integer function count_commas(row)
            character(len=*), intent(in) :: row
            integer :: k
            count_commas = 0
            do k = 1, len(row)
                if (row(k:k) == ',') count_commas = count_commas + 1
            end do
        end function count_commas

        !> The `.xdmf` text written to `path` for the set-aside folder: its snapshots of steps
        !> up to after_step stay in the folder above (the copy named them bare, and in the
        !> folder only the moved, later steps opened). Each is linked into the folder (a hard
        !> link: no copy, and it stays whole there when a later run moves or replaces the
        !> one above); where a link cannot be made, the copy names it as `../<name>`. Written
        !> piece by piece (a series of 10^4 snapshots is MBs of text).
        subroutine write_series_copy(xdmf, path, st)
            character(len=*), intent(in) :: xdmf, path
            integer, intent(out) :: st
            character(len=*), parameter :: MARK = 'Format="HDF">'
            type(text_buffer_t) :: copy, links
            character(len=:), allocatable :: reason, name
            integer :: at, colon, k, link_stat
            integer(i8) :: step, last_step
            logical :: linked
            last_step = -1_i8
            linked = .true.
            at = 1
            do
                k = index(xdmf(at:), MARK)
                if (k == 0) exit
                k = at + k - 1 + len(MARK)
                call copy%put(xdmf(at:k - 1))
                colon = index(xdmf(k:), ':')
                at = k
                if (colon == 0) cycle
                step = earlier_file_step(xdmf(k:k + colon - 2), case_name)
                if (step < 0_i8 .or. step > after_step) cycle
                ! (a step's many items name one file: linked once)
                if (step /= last_step) then
                    call link_file(directory // '/' // xdmf(k:k + colon - 2), folder // '/' // &
                        xdmf(k:k + colon - 2), link_stat)
                    linked = link_stat == 0
                    if (linked) call links%put(xdmf(k:k + colon - 2) // new_line('a'))
                    last_step = step
                end if
                if (.not. linked) call copy%put('../')
            end do
            call copy%put(xdmf(at:))
            ! (a copy that could not be written whole is not left half-written)
            call write_text_file_whole(path, copy%text(1:copy%used), st, reason)
            if (st == 0) return
            errmsg = "cannot write '" // path // "': " // reason
            ! the links go (the originals stay where they are), so the folder empties
            at = 1
            do while (at <= links%used)
                call next_line(links%text(1:links%used), at, name)
                call delete_file(folder // '/' // name)
            end do
        end subroutine write_series_copy

        !> The first `<directory>/<case>_earlier_<N>` that does not exist, made.
        subroutine new_folder(path, st)
            character(len=:), allocatable, intent(out) :: path
            integer, intent(out) :: st
            integer :: m
            character(len=16) :: digits
            st = 1
            do m = 1, MAX_EARLIER
                write(digits, '(i0)') m
                path = directory // '/' // case_name // '_earlier_' // trim(digits)
                inquire(file=path // '/.', exist=exists)
                if (exists) cycle
                inquire(file=path, exist=exists)
                if (exists) cycle
                call make_directories(path, st)
                made_folder = st == 0
                return
            end do
            ! (none free: no folder of this run's to name)
            path = ''
        end subroutine new_folder
    end subroutine set_aside_earlier_output

    !> The whole of a text file (rank 0's reads); st /= 0 when it cannot be read.
    subroutine read_whole(path, text, st)
        character(len=*), intent(in) :: path
        character(len=:), allocatable, intent(out) :: text
        integer, intent(out) :: st
        integer :: unit
        integer(i8) :: size_bytes
        open(newunit=unit, file=path, access='stream', form='unformatted', status='old', &
            action='read', iostat=st)
        if (st /= 0) then
            text = ''
            return
        end if
        inquire(unit=unit, size=size_bytes)
        if (size_bytes < 0) then
            st = 1
            text = ''
        else
            allocate(character(len=size_bytes) :: text)
            if (size_bytes > 0) read(unit, iostat=st) text
        end if
        close(unit)
    end subroutine read_whole
end module sph_earlier_output
