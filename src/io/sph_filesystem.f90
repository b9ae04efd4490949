!> File-system operations Fortran lacks, in one place: mkdir -p, rename, link, delete, directory
!> listing, checked text-file writes and free space (libc through bind(C); the listing
!> through sph_directory.c, the writes and free space through sph_file_write.c). Serial: the
!> caller decides which rank acts.
module sph_filesystem
    use, intrinsic :: iso_c_binding, only: c_char, c_int, c_long_long, c_null_char
    use sph_kinds, only: i8, wp
    use sph_logger, only: mb_text
    implicit none
    private
    public :: make_directories, rename_file, link_file, delete_file, list_directory
    public :: remove_empty_directory, entry_kind, unlink_if_link
    public :: ENTRY_NONE, ENTRY_FILE, ENTRY_LINK, ENTRY_DIRECTORY, ENTRY_OTHER
    public :: ENTRY_LINK_TO_DEVICE
    public :: write_text_file, write_text_file_whole, free_bytes, ends_with_new_line
    public :: disk_hint
    public :: lock_for_process, LOCK_HELD, LOCK_BUSY, LOCK_UNSUPPORTED, LOCK_FAILED

    !> lock_for_process's answers: held; held by another process; the file system has no
    !> locks; the lock file cannot be made
    integer, parameter :: LOCK_HELD = 0, LOCK_BUSY = 1, LOCK_UNSUPPORTED = 2, LOCK_FAILED = 3
    !> entry_kind's answers (a link is not followed)
    integer, parameter :: ENTRY_NONE = 0, ENTRY_FILE = 1, ENTRY_LINK = 2, ENTRY_DIRECTORY = 3
    integer, parameter :: ENTRY_OTHER = 4, ENTRY_LINK_TO_DEVICE = 5
    public :: text_buffer_t
    public :: MAX_FILE_PATH

    !> Text built up piece by piece (an .xdmf of 10^4 snapshots is MBs: appending to a
    !> character variable would copy it at every piece); text(1:used) is the content.
    type :: text_buffer_t
        character(len=:), allocatable :: text
        integer :: used = 0
    contains
        procedure :: put => text_buffer_put
    end type text_buffer_t

    !> The longest file path handed to HDF5 over MPI-IO: Open MPI's I/O component (4.1)
    !> builds names in a fixed buffer and aborts the process beyond about 243 characters
    !> ("buffer overflow detected", measured with output folders of 200-225 characters).
    integer, parameter :: MAX_FILE_PATH = 240

    interface
        integer(c_int) function c_mkdir(path, mode) bind(C, name="mkdir")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
            integer(c_int), value :: mode
        end function c_mkdir
        integer(c_int) function c_rename(old, new) bind(C, name="rename")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: old(*), new(*)
        end function c_rename
        integer(c_int) function c_rmdir(path) bind(C, name="rmdir")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
        end function c_rmdir
        integer(c_int) function c_link(old, new) bind(C, name="link")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: old(*), new(*)
        end function c_link
        integer(c_int) function c_unlink_path(path) bind(C, name="unlink")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
        end function c_unlink_path
        integer(c_int) function c_entry_kind(path) bind(C, name="sph_entry_kind")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
        end function c_entry_kind
        integer(c_int) function c_list_directory(path, buffer, capacity) &
                bind(C, name="sph_list_directory")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
            character(kind=c_char), intent(out) :: buffer(*)
            integer(c_int), value :: capacity
        end function c_list_directory
        integer(c_int) function c_write_bytes(path, data, n, append, message, capacity) &
                bind(C, name="sph_write_bytes")
            import :: c_char, c_int, c_long_long
            character(kind=c_char), intent(in) :: path(*), data(*)
            integer(c_long_long), value :: n
            integer(c_int), value :: append, capacity
            character(kind=c_char), intent(out) :: message(*)
        end function c_write_bytes
        integer(c_int) function c_lock_file(path, holder, capacity) bind(C, name="sph_lock_file")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
            character(kind=c_char), intent(out) :: holder(*)
            integer(c_int), value :: capacity
        end function c_lock_file
        integer(c_long_long) function c_free_bytes(path) bind(C, name="sph_free_bytes")
            import :: c_char, c_long_long
            character(kind=c_char), intent(in) :: path(*)
        end function c_free_bytes
    end interface

    integer, parameter :: listing_capacity = 4 * 1024 * 1024

contains

    !> mkdir -p. stat /= 0 when a component cannot be made.
    subroutine make_directories(path, stat)
        character(len=*), intent(in) :: path
        integer, intent(out) :: stat
        integer :: k
        logical :: exists
        integer(c_int) :: rc
        stat = 0
        do k = 2, len_trim(path) + 1
            if (k <= len_trim(path)) then
                if (path(k:k) /= '/') cycle
            end if
            inquire(file=path(1:k - 1) // '/.', exist=exists)
            if (exists) cycle
            ! (the umask decides, as for the files: a group's shared folder stays the group's)
            rc = c_mkdir(path(1:k - 1) // c_null_char, int(o'777', c_int))
            inquire(file=path(1:k - 1) // '/.', exist=exists)
            if (.not. exists) then
                stat = 1
                return
            end if
        end do
    end subroutine make_directories

    !> Atomic rename within a file system. stat /= 0 on failure.
    subroutine rename_file(from, to, stat)
        character(len=*), intent(in) :: from, to
        integer, intent(out) :: stat
        stat = 0
        if (c_rename(from // c_null_char, to // c_null_char) /= 0) stat = 1
    end subroutine rename_file

    !> A second name `to` for the file `from` (a hard link: no copy, and the file stays
    !> whole under `to` when `from` is later moved or removed). stat /= 0 on failure (another
    !> file system, a file system without links, `to` exists).
    subroutine link_file(from, to, stat)
        character(len=*), intent(in) :: from, to
        integer, intent(out) :: stat
        stat = 0
        if (c_link(from // c_null_char, to // c_null_char) /= 0) stat = 1
    end subroutine link_file

    !> What the entry `path` is (ENTRY_*), without following a link: a dangling link exists
    !> as one, where Fortran's INQUIRE says no file.
    integer function entry_kind(path)
        character(len=*), intent(in) :: path
        entry_kind = int(c_entry_kind(path // c_null_char))
    end function entry_kind

    !> Remove `path` when it is a symbolic link (the link, not what it points at): a file
    !> written under a name of the run's own (its .tmp names) is then made where the name
    !> says, in the output folder, never through a link to a file elsewhere (a link at
    !> CASE_000010.h5.tmp had the run write its snapshot over the link's target, a user's
    !> file, and rename the link to the snapshot's name; fz40). A link to a character device
    !> stays (the tests' /dev/full standing in for a full disk: a device keeps no file).
    subroutine unlink_if_link(path)
        character(len=*), intent(in) :: path
        integer(c_int) :: rc
        if (entry_kind(path) == ENTRY_LINK) rc = c_unlink_path(path // c_null_char)
    end subroutine unlink_if_link

    !> Remove a folder if it is empty (else, or when it cannot be removed, it stays).
    subroutine remove_empty_directory(path)
        character(len=*), intent(in) :: path
        integer(c_int) :: rc
        rc = c_rmdir(path // c_null_char)
    end subroutine remove_empty_directory

    !> Remove a file if it exists.
    subroutine delete_file(path)
        character(len=*), intent(in) :: path
        integer :: unit, stat
        open(newunit=unit, file=path, status='old', iostat=stat)
        if (stat == 0) close(unit, status='delete')
    end subroutine delete_file

    !> The entry names of a directory, each followed by a new line. stat /= 0 when it cannot
    !> be read.
    subroutine list_directory(path, listing, stat)
        character(len=*), intent(in) :: path
        character(len=:), allocatable, intent(out) :: listing
        integer, intent(out) :: stat
        character(kind=c_char), allocatable :: buffer(:)
        integer :: used, k
        allocate(buffer(listing_capacity))
        used = c_list_directory(trim(path) // c_null_char, buffer, listing_capacity)
        stat = merge(0, 1, used >= 0)
        listing = repeat(' ', max(used, 0))
        do k = 1, used
            listing(k:k) = buffer(k)
        end do
    end subroutine list_directory

    !> Write `text` to `path`, replacing it, or after its contents with append = .true. (a
    !> failed append leaves the file as it was). Every write and the close are checked (a
    !> Fortran WRITE to a full disk reports nothing). stat /= 0 and errmsg (the system's
    !> reason, e.g. 'No space left on device') on failure.
    subroutine write_text_file(path, text, stat, errmsg, append)
        character(len=*), intent(in) :: path, text
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        logical, intent(in), optional :: append
        character(kind=c_char, len=200) :: message
        integer(c_int) :: mode
        mode = 0
        if (present(append)) mode = merge(1, 0, append)
        message = ''
        stat = int(c_write_bytes(path // c_null_char, text, int(len(text), c_long_long), mode, &
            message, len(message, c_int)))
        errmsg = trim(message)
    end subroutine write_text_file

    !> Write `text` to `path` whole or not at all: under `path`.tmp, renamed when complete;
    !> on failure the .tmp is removed and `path` is as it was.
    subroutine write_text_file_whole(path, text, stat, errmsg)
        character(len=*), intent(in) :: path, text
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        call unlink_if_link(path // '.tmp')
        call write_text_file(path // '.tmp', text, stat, errmsg)
        if (stat == 0) then
            call rename_file(path // '.tmp', path, stat)
            if (stat /= 0) errmsg = "cannot rename it from '" // path // ".tmp'"
        end if
        if (stat /= 0) call delete_file(path // '.tmp')
    end subroutine write_text_file_whole

    !> Take an advisory lock on the file `path` (made if missing) for the rest of the process:
    !> the system releases it when the process ends, however it ends, so it is never left
    !> stale. stat: LOCK_HELD; LOCK_BUSY (another process holds it: `about` is the file's
    !> note of who, where and since when); LOCK_UNSUPPORTED (the file system has no locks);
    !> LOCK_FAILED (`about` is the reason).
    subroutine lock_for_process(path, stat, about)
        character(len=*), intent(in) :: path
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: about
        character(kind=c_char, len=300) :: holder
        holder = ''
        stat = int(c_lock_file(path // c_null_char, holder, len(holder, c_int)))
        about = trim(holder)
    end subroutine lock_for_process

    !> Whether the file `path` is empty or ends with a new line (a missing or unreadable
    !> file counts as ending with one).
    logical function ends_with_new_line(path)
        character(len=*), intent(in) :: path
        integer :: unit, stat
        integer(i8) :: bytes
        character :: last
        ends_with_new_line = .true.
        open(newunit=unit, file=path, access='stream', form='unformatted', status='old', &
            action='read', iostat=stat)
        if (stat /= 0) return
        inquire(unit=unit, size=bytes)
        if (bytes > 0) then
            read(unit, pos=bytes, iostat=stat) last
            if (stat == 0) ends_with_new_line = last == new_line('a')
        end if
        close(unit)
    end function ends_with_new_line

    !> Bytes free for writing on the file system that holds `path` (a file or folder that
    !> exists); -1 when that cannot be asked.
    integer(i8) function free_bytes(path)
        character(len=*), intent(in) :: path
        free_bytes = int(c_free_bytes(trim(path) // c_null_char), i8)
    end function free_bytes

    !> For a message on a failed write of the file `path`: ' (its file system has N MB free:
    !> ...)' when its folder's file system has less than 16 MB free, else '' (HDF5 gives no
    !> reason, and a disk that fills while a file is written is the usual one).
    function disk_hint(path) result(hint)
        character(len=*), intent(in) :: path
        character(len=:), allocatable :: hint
        integer(i8) :: free
        integer :: k
        k = index(path, '/', back=.true.)
        if (k > 1) then
            free = free_bytes(path(1:k - 1))
        else if (k == 1) then
            free = free_bytes('/')
        else
            free = free_bytes('.')
        end if
        hint = ''
        if (free >= 0 .and. free < 16_i8 * 1024_i8**2) hint = ' (its file system has ' // &
            mb_text(real(free, wp)) // ' free: the disk is full, or a quota reached?)'
    end function disk_hint

    !> Append `piece` to the buffer (its storage doubles as needed).
    subroutine text_buffer_put(buffer, piece)
        class(text_buffer_t), intent(inout) :: buffer
        character(len=*), intent(in) :: piece
        character(len=:), allocatable :: grown
        if (.not. allocated(buffer%text)) allocate(character(len=max(4096, len(piece))) :: &
            buffer%text)
        if (buffer%used + len(piece) > len(buffer%text)) then
            allocate(character(len=max(2 * len(buffer%text), buffer%used + len(piece))) :: grown)
            grown(1:buffer%used) = buffer%text(1:buffer%used)
            call move_alloc(grown, buffer%text)
        end if
        buffer%text(buffer%used + 1:buffer%used + len(piece)) = piece
        buffer%used = buffer%used + len(piece)
    end subroutine text_buffer_put
end module sph_filesystem
