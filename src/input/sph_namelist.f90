!> Fortran namelist text parsed into groups of key -> value tokens, and the declaration API
!> through which each owning module reads its keys.
!>
!> Syntax: `&group key = value, key(2) = v, arr = 1.0, 2.0, key(1,4) = 2.5e-5, key(1:3,4) =
!> a, b, c, 3*0.0, 'str', "str" (with & / ! inside), .true./T, ! comments, several pairs per
!> line, values over several lines /` (or `&end`). Groups are kept in file order, so a group
!> given several times yields several instances (for owners that ask for a list).
!>
!> An owner reads its keys with `grp%get_real('rho0', x, default=..., min_exclusive=..., unit=
!> ..., doc=...)` and friends. Each call records the key (for the unknown-key check and the
!> documentation registry), converts the tokens with Fortran's list-directed read (so values
!> are bit-identical to a namelist read), checks type and range, collects every error, and
!> appends the resolved value, round-trip exact, to the group's resolved text.
module sph_namelist
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite, ieee_overflow, &
        ieee_get_halting_mode, ieee_set_halting_mode, ieee_set_flag
    use sph_kinds, only: wp
    implicit none
    private
    public :: nml_file_t, nml_group_t, nml_key_t, nml_parse, real_text

    character(len=*), parameter :: nl = new_line('a')
    !> Magnitudes a real value may have (besides 0): convert_reals.
    real(wp), parameter :: MIN_MAGNITUDE = 1.0e-30_wp, MAX_MAGNITUDE = 1.0e30_wp
    character(len=*), parameter :: name_chars = &
        'abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_%'

    type :: nml_value_t
        character(len=:), allocatable :: text   !< token; strings without their quotes
        logical :: quoted = .false.
        logical :: null = .false.                !< an empty entry: leaves the element as it is
        integer :: line = 0                      !< where the value is (its key may be above)
    end type nml_value_t

    !> One assignment `key(subscript) = values`.
    type :: nml_item_t
        character(len=:), allocatable :: key, subscript
        type(nml_value_t), allocatable :: values(:)
        integer :: line = 0
        logical :: used = .false.
    end type nml_item_t

    !> A declared key, as documented: the registry behind doc checks and error messages.
    type, public :: nml_key_t
        character(len=:), allocatable :: group, key, kind, default, range, unit, doc
    end type nml_key_t

    type :: nml_group_t
        character(len=:), allocatable :: name
        integer :: line = 0                      !< line of `&name`; 0 = group absent
        type(nml_item_t), allocatable :: items(:)
        type(nml_key_t), allocatable :: keys(:)  !< declared keys, in declaration order
        character(len=:), allocatable :: resolved !< `    key = value` lines
        character(len=:), allocatable :: errors  !< one line per error, each starting nl
        !> one line per note (a key given that has no effect here), each 'note: ...' and
        !> starting nl
        character(len=:), allocatable :: notes
        integer :: n_errors = 0
        !> the unknown keys' errors of errors (group_finish), apart: config_parse reports
        !> them alone, since a misspelt key leaves its default and what follows misleads
        character(len=:), allocatable :: unknown
        integer :: n_unknown = 0
        !> the errors of the values given (conversion, range, choices, counts: the getters'),
        !> apart: config_parse reports them alone, since the checks across keys then read
        !> defaults that nobody wrote
        character(len=:), allocatable :: direct
        integer :: n_direct = 0
        integer :: instance = 0                  !< of a repeated group (1, 2, ...); 0: single
    contains
        procedure :: get_real, get_int, get_logical, get_string
        procedure :: get_real_array, get_real_matrix, get_string_array, get_real_list
        procedure :: error => group_error
        procedure :: value_error => group_value_error
        procedure :: note => group_note, note_if_given
        procedure :: finish => group_finish
        procedure :: to_text => group_to_text
        procedure, private :: find, find_all, declare, convert_reals, element_order
    end type nml_group_t

    type :: nml_file_t
        character(len=:), allocatable :: source
        type(nml_group_t), allocatable :: groups(:)
    contains
        procedure :: check_groups, take, take_all
    end type nml_file_t

    !> Text helpers the parser and the getters share, in the parser's submodule (gfortran
    !> makes a private module procedure local to the module's object file, where a submodule
    !> cannot call it).
    interface
        module function itoa(i) result(text)
            integer, intent(in) :: i
            character(len=:), allocatable :: text
        end function itoa
        !> Text for a message: bytes outside printable ASCII (a binary or mis-encoded file's,
        !> a control character) shown as \xNN.
        module function printable(text) result(shown)
            character(len=*), intent(in) :: text
            character(len=:), allocatable :: shown
        end function printable
        module pure function to_lower(s) result(out)
            character(len=*), intent(in) :: s
            character(len=:), allocatable :: out
        end function to_lower
        !> A name as keys are spelt: a letter, then letters, digits and underscores.
        module pure logical function is_name(token) result(yes)
            character(len=*), intent(in) :: token
        end function is_name
    end interface

    !> The parser: sph_namelist_parse.f90 (a submodule).
    interface
        !> Split text into groups of assignments. Syntax errors (an unterminated group or string,
        !> a value without a key) stop with stat /= 0 and a message naming source, line and group.
        module subroutine nml_parse(raw_text, source, file, stat, errmsg)
            character(len=*), intent(in) :: raw_text, source
            type(nml_file_t), intent(out) :: file
            integer, intent(out) :: stat
            character(len=:), allocatable, intent(out) :: errmsg
        end subroutine nml_parse
    end interface

contains


    ! ======================== groups: checks and lookup ========================

    !> Refuse unknown groups (listing the allowed ones) and a group given more than once unless
    !> its owner reads a list of them. Errors are appended to errmsg; stat counts them.
    subroutine check_groups(self, allowed, lists, stat, errmsg)
        class(nml_file_t), intent(in) :: self
        character(len=*), intent(in) :: allowed(:), lists(:)
        integer, intent(inout) :: stat
        character(len=:), allocatable, intent(inout) :: errmsg
        integer :: g, h, count, first
        do g = 1, size(self%groups)
            associate (name => self%groups(g)%name)
                if (.not. any(name == allowed)) then
                    stat = stat + 1
                    errmsg = errmsg // nl // '  ' // self%source // ':' // &
                        itoa(self%groups(g)%line) // ': unknown namelist group &' // name // &
                        suggestion(name, allowed) // ' Allowed groups: ' // &
                        join(allowed, ', &', '&')
                    cycle
                end if
                if (any(name == lists)) cycle
                count = 0
                first = 0
                do h = 1, g - 1
                    if (self%groups(h)%name /= name) cycle
                    count = count + 1
                    if (first == 0) first = h
                end do
                ! (both lines: the first was not named, fz48)
                if (count == 1) then
                    stat = stat + 1
                    errmsg = errmsg // nl // '  ' // self%source // ':' // &
                        itoa(self%groups(g)%line) // ': namelist group &' // name // &
                        ' appears more than once (first on line ' // &
                        itoa(self%groups(first)%line) // '); give each group once'
                end if
            end associate
        end do
    end subroutine check_groups

    !> The one instance of a group (an empty instance if absent: every key keeps its default).
    function take(self, name) result(grp)
        class(nml_file_t), intent(in) :: self
        character(len=*), intent(in) :: name
        type(nml_group_t) :: grp
        integer :: g
        do g = 1, size(self%groups)
            if (self%groups(g)%name == name) then
                grp = self%groups(g)
                return
            end if
        end do
        grp%name = name
        allocate(grp%items(0), grp%keys(0))
        grp%resolved = ''
        grp%errors = ''
        grp%notes = ''
    end function take

    !> Every instance of a repeated group, in file order.
    function take_all(self, name) result(grps)
        class(nml_file_t), intent(in) :: self
        character(len=*), intent(in) :: name
        type(nml_group_t), allocatable :: grps(:)
        integer :: g
        allocate(grps(0))
        do g = 1, size(self%groups)
            if (self%groups(g)%name == name) grps = [grps, self%groups(g)]
        end do
    end function take_all

    !> Record an error against a key of this group: `  &group key: what`, or for an instance
    !> of a repeated group `  &group N key: what` (N counts the instances in file order).
    subroutine group_error(self, key, what)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key, what
        character(len=:), allocatable :: label
        self%n_errors = self%n_errors + 1
        label = '&' // self%name
        if (self%instance > 0) label = label // ' ' // itoa(self%instance) // ' (line ' // &
            itoa(self%line) // ')'
        self%errors = self%errors // nl // '  ' // label // ' ' // printable(key) // ': ' // &
            printable(what)
    end subroutine group_error

    !> text is well-formed UTF-8 (ASCII included): each lead byte followed by as many
    !> continuation bytes as it announces, no overlong two-byte forms.
    pure logical function valid_utf8(text)
        character(len=*), intent(in) :: text
        integer :: k, c, more, j
        valid_utf8 = .false.
        k = 1
        do while (k <= len(text))
            c = iachar(text(k:k))
            if (c < 128) then
                more = 0
            else if (c >= 194 .and. c <= 223) then
                more = 1
            else if (c >= 224 .and. c <= 239) then
                more = 2
            else if (c >= 240 .and. c <= 244) then
                more = 3
            else
                return
            end if
            if (k + more > len(text)) return
            do j = k + 1, k + more
                c = iachar(text(j:j))
                if (c < 128 .or. c > 191) return
            end do
            k = k + more + 1
        end do
        valid_utf8 = .true.
    end function valid_utf8

    !> An error in a value given (a getter's): recorded as group_error does, and apart.
    subroutine group_value_error(self, key, what)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key, what
        integer :: k
        if (.not. allocated(self%errors)) self%errors = ''
        if (.not. allocated(self%direct)) self%direct = ''
        k = len(self%errors)
        call self%error(key, what)
        self%direct = self%direct // self%errors(k + 1:)
        self%n_direct = self%n_direct + 1
    end subroutine group_value_error

    !> text holds one of ASCII's control characters (tab included: not in a string value).
    pure logical function has_control(text)
        character(len=*), intent(in) :: text
        integer :: k
        has_control = .false.
        do k = 1, len(text)
            if (iachar(text(k:k)) < 32 .or. iachar(text(k:k)) == 127) has_control = .true.
        end do
    end function has_control

    !> A note on key: not an error (the run goes on), printed after the resolved input.
    subroutine group_note(self, key, what)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key, what
        self%notes = self%notes // nl // 'note: &' // self%name // ' ' // key // ': ' // what
    end subroutine group_note

    !> A note when key was given in the input although it has no effect with the rest of
    !> it (a Tait exponent with another equation of state); `why` says why.
    subroutine note_if_given(self, key, why)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key, why
        integer :: i
        do i = 1, size(self%items)
            if (self%items(i)%key /= key) cycle
            ! `key =` with nothing after it sets nothing (a null value): no note
            if (all(self%items(i)%values%null)) cycle
            call self%note(key, 'given (line ' // itoa(self%items(i)%line) // ') but has ' // &
                'no effect: ' // why)
            return
        end do
    end subroutine note_if_given

    !> After the owner has declared its keys: every key given but not declared is an error,
    !> with the closest declared name suggested and the allowed keys listed.
    subroutine group_finish(self)
        class(nml_group_t), intent(inout) :: self
        integer :: i, k
        character(len=64), allocatable :: names(:)
        character(len=:), allocatable :: hint
        allocate(names(size(self%keys)))
        do k = 1, size(self%keys)
            names(k) = self%keys(k)%key
        end do
        if (.not. allocated(self%unknown)) self%unknown = ''
        if (.not. allocated(self%errors)) self%errors = ''
        do i = 1, size(self%items)
            if (self%items(i)%used) cycle
            hint = suggestion(self%items(i)%key, names)
            k = len(self%errors)
            call self%error(self%items(i)%key, 'unknown key (line ' // &
                itoa(self%items(i)%line) // ')' // hint // &
                ' Allowed keys in &' // self%name // ': ' // join(names, ', ', ''))
            self%unknown = self%unknown // self%errors(k + 1:)
            self%n_unknown = self%n_unknown + 1
        end do
    end subroutine group_finish

    !> The group with its resolved values, as namelist text.
    function group_to_text(self) result(text)
        class(nml_group_t), intent(in) :: self
        character(len=:), allocatable :: text
        text = '&' // self%name // nl // self%resolved // '/' // nl
    end function group_to_text

    ! ============================ declaration API ============================

    integer function find(self, key)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        integer :: i
        find = 0
        do i = 1, size(self%items)
            if (self%items(i)%key == key) then
                if (find /= 0) then
                    call self%value_error(key, 'given more than once (lines ' // &
                        itoa(self%items(find)%line) // ' and ' // &
                        itoa(self%items(i)%line) // ')')
                end if
                find = i
                self%items(i)%used = .true.
            end if
        end do
    end function find

    !> The assignments of an array key, in input order: an array may be assigned element
    !> by element (`wall_velocity(1,3) = 1e-3` and `wall_velocity(1,4) = -1e-3`), as
    !> Fortran's namelist input allows; the conversions refuse an element given twice.
    function find_all(self, key) result(found)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        integer, allocatable :: found(:)
        integer :: i
        allocate(found(0))
        do i = 1, size(self%items)
            if (self%items(i)%key /= key) cycle
            found = [found, i]
            self%items(i)%used = .true.
        end do
    end function find_all

    subroutine declare(self, key, kind, default, range, unit, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key, kind, default, range
        character(len=*), intent(in), optional :: unit, doc
        type(nml_key_t) :: d
        d = nml_key_t(group=self%name, key=key, kind=kind, default=default, range=range, &
            unit='', doc='')
        if (present(unit)) d%unit = unit
        if (present(doc)) d%doc = doc
        self%keys = [self%keys, d]
    end subroutine declare

    !> A real scalar with optional bounds; the error states the bounds and the unit.
    subroutine get_real(self, key, var, default, min, max, min_exclusive, max_exclusive, &
            unit, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        real(wp), intent(out) :: var
        real(wp), intent(in) :: default
        real(wp), intent(in), optional :: min, max, min_exclusive, max_exclusive
        character(len=*), intent(in), optional :: unit, doc
        real(wp) :: buf(1)
        buf = default
        call self%get_real_array(key, buf, default, min, max, min_exclusive, max_exclusive, &
            unit, doc, scalar=.true.)
        var = buf(1)
    end subroutine get_real

    !> A real array (filled from element 1, or from the subscript given: `key(2) = v`).
    subroutine get_real_array(self, key, var, default, min, max, min_exclusive, &
            max_exclusive, unit, doc, scalar)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        real(wp), intent(out) :: var(:)
        real(wp), intent(in) :: default
        real(wp), intent(in), optional :: min, max, min_exclusive, max_exclusive
        character(len=*), intent(in), optional :: unit, doc
        logical, intent(in), optional :: scalar
        character(len=:), allocatable :: range
        integer :: i, k, set_line(size(var))
        integer, allocatable :: items(:)
        logical :: is_scalar
        is_scalar = .false.
        if (present(scalar)) is_scalar = scalar
        range = range_text(min, max, min_exclusive, max_exclusive)
        if (is_scalar) then
            call self%declare(key, 'real', real_text(default), range, unit, doc)
        else
            call self%declare(key, 'real(' // itoa(size(var)) // ')', real_text(default), &
                range, unit, doc)
        end if
        var = default
        items = scalar_or_all(self, key, is_scalar)
        set_line = 0
        do i = 1, size(items)
            call self%convert_reals(self%items(items(i)), var, [size(var)], set_line)
        end do
        do k = 1, size(var)
            if (.not. in_range(var(k))) then
                if (is_scalar) then
                    call self%value_error(key, real_text(var(k)) // ' is out of range: must be ' // &
                        range // unit_suffix(unit) // given_at(set_line(k)))
                else
                    call self%value_error(key // '(' // itoa(k) // ')', real_text(var(k)) // &
                        ' is out of range: must be ' // range // unit_suffix(unit) // &
                        given_at(set_line(k)))
                end if
            end if
        end do
        call append_resolved(self, key, reals_text(var))
    contains
        logical function in_range(x)
            real(wp), intent(in) :: x
            in_range = .true.
            if (present(min)) in_range = in_range .and. x >= min
            if (present(max)) in_range = in_range .and. x <= max
            if (present(min_exclusive)) in_range = in_range .and. x > min_exclusive
            if (present(max_exclusive)) in_range = in_range .and. x < max_exclusive
        end function in_range
    end subroutine get_real_array

    !> A real rank-2 array, e.g. wall_velocity(3, 6); `key(1,4) = v` and `key(1:3,4) = a,b,c`.
    subroutine get_real_matrix(self, key, var, default, unit, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        real(wp), intent(out) :: var(:, :)
        real(wp), intent(in) :: default
        character(len=*), intent(in), optional :: unit, doc
        real(wp) :: flat(size(var))
        integer :: i, set_line(size(var))
        integer, allocatable :: items(:)
        call self%declare(key, 'real(' // itoa(size(var, 1)) // ',' // itoa(size(var, 2)) // &
            ')', real_text(default), '', unit, doc)
        flat = default
        items = self%find_all(key)
        set_line = 0
        do i = 1, size(items)
            call self%convert_reals(self%items(items(i)), flat, shape(var), set_line)
        end do
        var = reshape(flat, shape(var))
        call append_resolved(self, key, reals_text(flat))
    end subroutine get_real_matrix

    !> A list of reals of any length up to max_count (the length is what was given).
    subroutine get_real_list(self, key, var, max_count, min, unit, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        real(wp), allocatable, intent(out) :: var(:)
        integer, intent(in) :: max_count
        real(wp), intent(in), optional :: min
        character(len=*), intent(in), optional :: unit, doc
        real(wp) :: buf(max_count)
        logical :: given(max_count)
        integer :: i, k, n
        call self%declare(key, 'real list', 'none', range_text(min, null(), null(), null()), &
            unit, doc)
        buf = 0.0_wp
        given = .false.
        n = 0
        i = self%find(key)
        if (i /= 0) then
            if (len(self%items(i)%subscript) > 0) then
                call self%value_error(key, 'a list is given whole, without a subscript' // &
                    line_text(self%items(i)))
            else if (size(self%items(i)%values) > max_count) then
                call self%value_error(key, 'at most ' // itoa(max_count) // ' entries, got ' // &
                    itoa(size(self%items(i)%values)) // line_text(self%items(i)))
            else if (size(self%items(i)%values) == 1 .and. all(self%items(i)%values%null)) then
                ! `key =` (or `key = ,`): none, as the default
                continue
            else if (any(self%items(i)%values%null)) then
                call self%value_error(key, 'a list has no empty entries' // line_text(self%items(i)))
            else
                n = size(self%items(i)%values)
                call self%convert_reals(self%items(i), buf(1:n), [n])
            end if
        end if
        var = buf(1:n)
        do k = 1, n
            if (present(min)) then
                if (.not. var(k) >= min) call self%value_error(key, real_text(var(k)) // &
                    ' is out of range: must be ' // range_text(min, null(), null(), null()) &
                    // value_line_text(self%items(i), k))
            end if
        end do
        if (n == 0) then
            self%resolved = self%resolved // '    ! ' // key // ' = (none)' // nl
        else
            call append_resolved(self, key, reals_text(var))
        end if
    end subroutine get_real_list

    subroutine get_int(self, key, var, default, min, max, unit, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        integer, intent(out) :: var
        integer, intent(in) :: default
        integer, intent(in), optional :: min, max
        character(len=*), intent(in), optional :: unit, doc
        character(len=:), allocatable :: range, at
        integer :: i, ios
        range = ''
        if (present(min)) range = '>= ' // itoa(min)
        if (present(max)) then
            if (len(range) > 0) range = range // ' and '
            range = range // '<= ' // itoa(max)
        end if
        call self%declare(key, 'integer', itoa(default), range, unit, doc)
        var = default
        i = self%find(key)
        if (i /= 0) then
            if (single_value(self, i)) then
                associate (v => self%items(i)%values(1))
                    if (v%null) then
                        continue
                    else if (v%quoted) then
                        call self%value_error(key, "'" // v%text // "' is not an integer" // &
                            value_line_text(self%items(i), 1))
                    else
                        read(v%text, *, iostat=ios) var
                        if (ios /= 0) then
                            call self%value_error(key, "'" // v%text // "' is not an integer" // &
                                value_line_text(self%items(i), 1))
                            var = default
                        end if
                    end if
                end associate
            end if
        end if
        at = ''
        if (i /= 0) at = value_line_text(self%items(i), 1)
        if (present(min)) then
            if (var < min) call self%value_error(key, itoa(var) // ' is out of range: must be ' // &
                range // unit_suffix(unit) // at)
        end if
        if (present(max)) then
            if (var > max) call self%value_error(key, itoa(var) // ' is out of range: must be ' // &
                range // unit_suffix(unit) // at)
        end if
        call append_resolved(self, key, itoa(var))
    end subroutine get_int

    subroutine get_logical(self, key, var, default, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        logical, intent(out) :: var
        logical, intent(in) :: default
        character(len=*), intent(in), optional :: doc
        integer :: i, ios
        call self%declare(key, 'logical', logical_text(default), '', doc=doc)
        var = default
        i = self%find(key)
        if (i /= 0) then
            if (single_value(self, i)) then
                associate (v => self%items(i)%values(1))
                    if (v%null) then
                        continue
                    else if (v%quoted) then
                        call self%value_error(key, "'" // v%text // "' is not a logical" // &
                            value_line_text(self%items(i), 1))
                    else
                        read(v%text, *, iostat=ios) var
                        if (ios /= 0) then
                            call self%value_error(key, "'" // v%text // &
                                "' is not a logical (.true. or .false.)" // &
                                value_line_text(self%items(i), 1))
                            var = default
                        end if
                    end if
                end associate
            end if
        end if
        call append_resolved(self, key, logical_text(var))
    end subroutine get_logical

    !> A string; with choices, the value is compared and stored in lower case and must be one
    !> of them.
    subroutine get_string(self, key, var, default, choices, doc)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        character(len=*), intent(out) :: var
        character(len=*), intent(in) :: default
        character(len=*), intent(in), optional :: choices(:)
        character(len=*), intent(in), optional :: doc
        character(len=len(var)) :: buf(1)
        call self%get_string_array(key, buf, default, choices, doc, scalar=.true.)
        var = buf(1)
    end subroutine get_string

    subroutine get_string_array(self, key, var, default, choices, doc, scalar)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        character(len=*), intent(out) :: var(:)
        character(len=*), intent(in) :: default
        character(len=*), intent(in), optional :: choices(:)
        character(len=*), intent(in), optional :: doc
        logical, intent(in), optional :: scalar
        integer :: i, k, n, m, set_line(size(var))
        integer, allocatable :: order(:), items(:)
        character(len=:), allocatable :: range, shown
        logical :: is_scalar
        is_scalar = .false.
        if (present(scalar)) is_scalar = scalar
        range = ''
        if (present(choices)) range = join(choices, "', '", "'") // "'"
        if (is_scalar) then
            call self%declare(key, 'string', "'" // default // "'", range, doc=doc)
        else
            call self%declare(key, 'string(' // itoa(size(var)) // ')', "'" // default // "'", &
                range, doc=doc)
        end if
        var = default
        items = scalar_or_all(self, key, is_scalar)
        set_line = 0
        do m = 1, size(items)
            i = items(m)
            order = self%element_order(self%items(i), [size(var)])
            n = min(size(order), size(self%items(i)%values))
            ! as convert_reals: values beyond the elements are an error, not dropped
            if (size(order) > 0 .and. size(self%items(i)%values) > size(order)) &
                call self%value_error(key, itoa(size(self%items(i)%values)) // ' values for ' // &
                    itoa(size(order)) // ' element(s)' // line_text(self%items(i)) // &
                    missing_equals(self%items(i)))
            if (.not. claim_elements(self, self%items(i), order(1:n), [size(var)], set_line)) &
                cycle
            do k = 1, n
                associate (v => self%items(i)%values(k))
                    if (v%null) cycle
                    shown = element_label(key, order(k), [size(var)])
                    ! the standard's namelist input delimits strings: unquoted, a '!' in
                    ! the value started a comment and a '/' ended the group
                    if (.not. v%quoted) then
                        call self%value_error(shown, v%text // ' is not a quoted string (write ' // &
                            quote(v%text) // ')' // value_line_text(self%items(i), k))
                        cycle
                    end if
                    if (len(v%text) > len(var)) then
                        call self%value_error(shown, "'" // v%text // "' is longer than " // &
                            itoa(len(var)) // ' characters' // value_line_text(self%items(i), k))
                        cycle
                    end if
                    ! (they would reach the log and every output file's stored input raw)
                    if (has_control(v%text)) then
                        call self%value_error(shown, "'" // v%text // "' holds a control " // &
                            'character' // value_line_text(self%items(i), k))
                        cycle
                    end if
                    ! (Latin-1 bytes went raw into the HDF5 files' input, which readers take
                    ! as UTF-8: fz48)
                    if (.not. valid_utf8(v%text)) then
                        call self%value_error(shown, 'holds bytes that are not UTF-8 text (save ' // &
                            'the file as UTF-8)' // value_line_text(self%items(i), k))
                        cycle
                    end if
                    var(order(k)) = v%text
                end associate
            end do
        end do
        if (present(choices)) then
            do k = 1, size(var)
                var(k) = to_lower(var(k))
                if (any(var(k) == choices)) cycle
                shown = key
                if (.not. is_scalar) shown = key // '(' // itoa(k) // ')'
                ! (with the value's line and the nearest choice, as an unknown key has)
                call self%value_error(shown, "'" // trim(var(k)) // "' is not one of " // range // &
                    given_at(set_line(k)) // suggestion(trim(var(k)), choices))
            end do
        end if
        shown = ''
        do k = 1, size(var)
            if (k > 1) shown = shown // ', '
            shown = shown // quote(trim(var(k)))
        end do
        call append_resolved(self, key, shown)
    end subroutine get_string_array

    ! ============================== helpers ==============================

    !> The assignments to read for key: every one of an array's (find_all); a scalar's one,
    !> refused when given twice (find: even after an empty value) or with a subscript.
    function scalar_or_all(self, key, is_scalar) result(items)
        class(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key
        logical, intent(in) :: is_scalar
        integer, allocatable :: items(:)
        integer :: i
        if (.not. is_scalar) then
            items = self%find_all(key)
            return
        end if
        allocate(items(0))
        i = self%find(key)
        if (i == 0) return
        if (len(self%items(i)%subscript) > 0) then
            call self%value_error(key, 'a scalar takes no subscript' // line_text(self%items(i)))
            return
        end if
        items = [i]
    end function scalar_or_all

    logical function single_value(self, i)
        class(nml_group_t), intent(inout) :: self
        integer, intent(in) :: i
        single_value = .false.
        if (len(self%items(i)%subscript) > 0) then
            call self%value_error(self%items(i)%key, 'a scalar takes no subscript' // &
                line_text(self%items(i)))
        else if (size(self%items(i)%values) /= 1) then
            call self%value_error(self%items(i)%key, 'expects one value, got ' // &
                itoa(size(self%items(i)%values)) // line_text(self%items(i)) // &
                missing_equals(self%items(i)))
        else
            single_value = .true.
        end if
    end function single_value

    !> The elements item sets (order: their column-major indices, one per value; empty
    !> entries set none) claimed for it in set_line, the line that set each element (0:
    !> none yet); when one was set before, one error naming it and both lines, and nothing
    !> claimed: the item is then skipped.
    logical function claim_elements(self, item, order, shp, set_line) result(claimed)
        class(nml_group_t), intent(inout) :: self
        type(nml_item_t), intent(in) :: item
        integer, intent(in) :: order(:), shp(:)
        integer, intent(inout) :: set_line(:)
        integer :: k, element
        claimed = .true.
        do k = 1, min(size(order), size(item%values))
            if (item%values(k)%null) cycle
            element = order(k)
            if (set_line(element) == 0) cycle
            call self%value_error(element_label(item%key, element, shp), &
                'given more than once (lines ' // &
                itoa(set_line(element)) // ' and ' // itoa(value_line(item, k)) // ')')
            claimed = .false.
            return
        end do
        ! (the value's own line: a range or choice message names it)
        do k = 1, min(size(order), size(item%values))
            if (item%values(k)%null) cycle
            set_line(order(k)) = item%line
            if (item%values(k)%line > 0) set_line(order(k)) = item%values(k)%line
        end do
    end function claim_elements

    !> For a message about an assignment's value count: when one of its values after the
    !> first is a bare name (not T or F), most likely the next key with its '=' missing
    !> ('dx = 1.0e-4' then 'wall_velocity (1,3) 1.0e-4' on the next line), a note saying so.
    function missing_equals(item) result(text)
        type(nml_item_t), intent(in) :: item
        character(len=:), allocatable :: text
        integer :: k
        character(len=:), allocatable :: word
        text = ''
        do k = 2, size(item%values)
            associate (v => item%values(k))
                if (v%quoted .or. v%null) cycle
                if (.not. is_name(v%text)) cycle
                word = to_lower(v%text)
                if (word == 't' .or. word == 'f' .or. word == 'true' .or. word == 'false') cycle
                text = " ('" // v%text // "' is read as a value: is the '=' after it missing?)"
                return
            end associate
        end do
    end function missing_equals

    !> ` (line N)`: where an assignment is, for a message about its values.
    function line_text(item) result(text)
        type(nml_item_t), intent(in) :: item
        character(len=:), allocatable :: text
        text = ' (line ' // itoa(item%line) // ')'
    end function line_text

    !> ` (line N)`: where value k of an assignment is (a list continued over lines, a key
    !> whose '=' or value starts a later line: the key's line was named, fz42, fz48).
    function value_line_text(item, k) result(text)
        type(nml_item_t), intent(in) :: item
        integer, intent(in) :: k
        character(len=:), allocatable :: text
        text = ' (line ' // itoa(value_line(item, k)) // ')'
    end function value_line_text

    !> The line of value k of an assignment (its key's when not known).
    integer function value_line(item, k)
        type(nml_item_t), intent(in) :: item
        integer, intent(in) :: k
        value_line = item%line
        if (k >= 1 .and. k <= size(item%values)) then
            if (item%values(k)%line > 0) value_line = item%values(k)%line
        end if
    end function value_line

    !> ` (line N)` for a line known (> 0), else nothing (a default is on no line).
    function given_at(line) result(text)
        integer, intent(in) :: line
        character(len=:), allocatable :: text
        text = ''
        if (line > 0) text = ' (line ' // itoa(line) // ')'
    end function given_at

    !> `key(i,j)` for element (column-major index) of an array of shape shp; key alone for
    !> a scalar.
    function element_label(key, element, shp) result(shown)
        character(len=*), intent(in) :: key
        integer, intent(in) :: element, shp(:)
        character(len=:), allocatable :: shown
        integer :: d, rest
        shown = key
        if (product(shp) <= 1) return
        shown = shown // '('
        rest = element - 1
        do d = 1, size(shp)
            if (d > 1) shown = shown // ','
            shown = shown // itoa(mod(rest, shp(d)) + 1)
            rest = rest / shp(d)
        end do
        shown = shown // ')'
    end function element_label

    !> Convert the tokens of one assignment into var (shape given, column-major), by the
    !> list-directed read Fortran's namelist input uses. set_line: the line that set each
    !> element so far (0: none), for an array assigned in several parts.
    subroutine convert_reals(self, item, var, shp, set_line)
        class(nml_group_t), intent(inout) :: self
        type(nml_item_t), intent(in) :: item
        real(wp), intent(inout) :: var(:)
        integer, intent(in) :: shp(:)
        integer, intent(inout), optional :: set_line(:)
        integer, allocatable :: order(:)
        integer :: k, ios
        real(wp) :: x
        logical :: halting
        character(len=:), allocatable :: shown, at_line
        order = self%element_order(item, shp)
        if (size(order) == 0) return
        if (size(item%values) > size(order)) then
            call self%value_error(item%key, itoa(size(item%values)) // ' values for ' // &
                itoa(size(order)) // ' element(s)' // line_text(item) // missing_equals(item))
            return
        end if
        if (present(set_line)) then
            if (.not. claim_elements(self, item, order, shp, set_line)) return
        end if
        do k = 1, size(item%values)
            associate (v => item%values(k))
                if (v%null) cycle
                shown = element_label(item%key, order(k), shp)
                at_line = value_line_text(item, k)
                if (v%quoted) then
                    call self%value_error(shown, "'" // v%text // "' is not a real number" // at_line)
                    cycle
                end if
                ! a value beyond huge() reads as Infinity and raises the overflow flag, which
                ! Debug builds trap: not halted for the read, refused below
                call ieee_get_halting_mode(ieee_overflow, halting)
                call ieee_set_halting_mode(ieee_overflow, .false.)
                read(v%text, *, iostat=ios) x
                call ieee_set_flag(ieee_overflow, .false.)
                call ieee_set_halting_mode(ieee_overflow, halting)
                if (ios /= 0) then
                    call self%value_error(shown, "'" // v%text // "' is not a real number" // at_line)
                    cycle
                end if
                ! NaN, Infinity and overflowing values (1e400 reads as Infinity) would pass
                ! range checks that compare false and break the code that prints them
                if (.not. ieee_is_finite(x)) then
                    call self%value_error(shown, "'" // v%text // "' is not a finite number" // &
                        at_line)
                    cycle
                end if
                ! no key means anything beyond these magnitudes (SI units), and products,
                ! squares and ratios of such values (h^2 / nu, t_end / dt) overflow; a
                ! value that underflows to 0 (1e-400: 0 means 'automatic' for some keys)
                ! is below them too
                if ((x /= 0.0_wp .and. (abs(x) < MIN_MAGNITUDE .or. abs(x) > MAX_MAGNITUDE)) &
                    .or. (x == 0.0_wp .and. nonzero_mantissa(v%text))) then
                    call self%value_error(shown, "'" // v%text // "' is outside the magnitudes " // &
                        'sphremesh computes with (0, or 1e-30 to 1e30 in SI units)' // at_line)
                    cycle
                end if
                var(order(k)) = x
            end associate
        end do
    end subroutine convert_reals

    !> Whether a number's digits before its exponent are not all zero ('1e-400', not
    !> '0.0e5' nor '0.0-5', Fortran's exponent without a letter).
    logical function nonzero_mantissa(text)
        character(len=*), intent(in) :: text
        integer :: e, sign_at
        e = scan(text, 'eEdDqQ')
        if (e == 0) e = len(text) + 1
        ! a sign after the first character starts an exponent too
        if (len(text) > 1) then
            sign_at = scan(text(2:), '+-')
            if (sign_at > 0) e = min(e, sign_at + 1)
        end if
        nonzero_mantissa = scan(text(1:e - 1), '123456789') > 0
    end function nonzero_mantissa

    !> An integer subscript bound: digits with an optional sign and blanks around them;
    !> ios /= 0 for anything else.
    subroutine read_index(text, value, ios)
        character(len=*), intent(in) :: text
        integer, intent(out) :: value, ios
        character(len=:), allocatable :: t
        integer :: first, k
        value = 0
        ios = 1
        t = text
        ! (a tab is a blank here, as the list-directed read took it)
        do k = 1, len(t)
            if (t(k:k) == achar(9)) t(k:k) = ' '
        end do
        t = trim(adjustl(t))
        first = 1
        if (len(t) > 0) then
            if (t(1:1) == '+' .or. t(1:1) == '-') first = 2
        end if
        if (len(t) < first) return
        if (verify(t(first:), '0123456789') /= 0) return
        read(t, *, iostat=ios) value
    end subroutine read_index

    !> Element indices (column-major, 1-based) that the values of an assignment fill: all of
    !> the array without a subscript; from one element on for `key(i,j)`; the section for
    !> `key(lo:hi, j)`.
    function element_order(self, item, shp) result(order)
        class(nml_group_t), intent(inout) :: self
        type(nml_item_t), intent(in) :: item
        integer, intent(in) :: shp(:)
        integer, allocatable :: order(:)
        character(len=:), allocatable :: parts(:)
        integer :: lo(size(shp)), hi(size(shp)), idx(size(shp)), d, c, ios, start, stride
        logical :: section
        allocate(order(0))
        if (len(item%subscript) == 0) then
            order = [(d, d = 1, product(shp))]
            return
        end if
        call split_commas(item%subscript, parts)
        if (size(parts) /= size(shp)) then
            call self%value_error(item%key, '(' // item%subscript // ') needs ' // itoa(size(shp)) // &
                ' subscript(s)' // line_text(item))
            return
        end if
        section = .false.
        do d = 1, size(shp)
            c = index(parts(d), ':')
            if (c > 0 .and. index(parts(d)(c + 1:), ':') > 0) then
                call self%value_error(item%key, '(' // item%subscript // '): a stride (lo:hi:step) ' // &
                    'is not supported; give a range lo:hi or the elements one by one' // &
                    line_text(item))
                return
            end if
            ! (each bound an integer and nothing else: a list-directed read took '2 1', '2/3',
            ! '1*2' or '2;9' as 2, and left the bound unset for '/' or '3*')
            if (c == 0) then
                call read_index(parts(d), lo(d), ios)
                hi(d) = lo(d)
            else
                section = .true.
                lo(d) = 1
                hi(d) = shp(d)
                ios = 0
                if (len_trim(parts(d)(1:c - 1)) > 0) &
                    call read_index(parts(d)(1:c - 1), lo(d), ios)
                if (ios == 0 .and. len_trim(parts(d)(c + 1:)) > 0) &
                    call read_index(parts(d)(c + 1:), hi(d), ios)
            end if
            if (ios /= 0) then
                call self%value_error(item%key, '(' // item%subscript // "): '" // &
                    trim(adjustl(parts(d))) // "' is not an integer subscript or range lo:hi" // &
                    line_text(item))
                return
            end if
            if (lo(d) > hi(d)) then
                call self%value_error(item%key, '(' // item%subscript // '): the range ' // &
                    itoa(lo(d)) // ':' // itoa(hi(d)) // ' is empty (lo above hi)' // &
                    line_text(item))
                return
            end if
            if (lo(d) < 1 .or. hi(d) > shp(d)) then
                call self%value_error(item%key, '(' // item%subscript // ') is outside (' // &
                    join_ints(shp) // ')' // line_text(item))
                return
            end if
        end do
        if (.not. section) then   ! from this element on, in array element order
            start = 1
            stride = 1
            do d = 1, size(shp)
                start = start + (lo(d) - 1) * stride
                stride = stride * shp(d)
            end do
            order = [(d, d = start, product(shp))]
            return
        end if
        idx = lo
        do
            start = 1
            stride = 1
            do d = 1, size(shp)
                start = start + (idx(d) - 1) * stride
                stride = stride * shp(d)
            end do
            order = [order, start]
            d = 1
            do while (d <= size(shp))
                if (idx(d) < hi(d)) exit
                idx(d) = lo(d)
                d = d + 1
            end do
            if (d > size(shp)) exit
            idx(d) = idx(d) + 1
        end do
    end function element_order

    !> `    key = value`, continued on further lines after a comma when it grows past 90
    !> characters (namelist values may span lines).
    subroutine append_resolved(self, key, value)
        type(nml_group_t), intent(inout) :: self
        character(len=*), intent(in) :: key, value
        character(len=:), allocatable :: line
        integer :: k, start, cut
        logical :: in_quote
        line = '    ' // key // ' = '
        start = 1
        cut = 0
        in_quote = .false.
        do k = 1, len(value)
            if (value(k:k) == "'") in_quote = .not. in_quote
            if (.not. in_quote .and. value(k:k) == ',') cut = k
            if (len(line) + k - start + 1 > 90 .and. cut >= start) then
                self%resolved = self%resolved // line // value(start:cut) // nl
                line = '        '
                start = cut + 2
            end if
        end do
        self%resolved = self%resolved // line // value(start:) // nl
    end subroutine append_resolved

    !> Shortest decimal text that reads back to exactly x (at most 17 significant digits).
    function real_text(x) result(text)
        real(wp), intent(in) :: x
        character(len=:), allocatable :: text
        character(len=40) :: buf
        character(len=16) :: fmt
        real(wp) :: back
        integer :: d, e, ex
        if (x == 0.0_wp) then
            text = '0.0'
            if (sign(1.0_wp, x) < 0.0_wp) text = '-0.0'
            return
        end if
        ! (positional up to a million: 1e10 reads better than 10000000000.0)
        if (abs(x) < 1.0e7_wp .and. abs(x) >= 1.0_wp) then
            if (x == aint(x)) then
                write(buf, '(f0.1)') x
                text = trim(adjustl(buf))
                return
            end if
        end if
        do d = 0, 16
            write(fmt, '(a, i0, a)') '(es40.', d, 'e3)'
            write(buf, fmt) x
            if (abs(x) > 1.0e300_wp) cycle   ! a shorter form may round past huge()
            read(buf, *) back
            if (back == x) exit
        end do
        d = min(d, 16)
        buf = adjustl(buf)
        e = index(buf, 'E')
        read(buf(e + 1:), *) ex
        if (ex >= -4 .and. ex < 7) then   ! positional form with the same digits
            write(fmt, '(a, i0, a)') '(f40.', max(1, d - ex), ')'
            write(buf, fmt) x
            text = trim(adjustl(buf))
            read(text, *) back
            if (back == x) return
            write(fmt, '(a, i0, a)') '(es40.', d, 'e3)'
            write(buf, fmt) x
            buf = adjustl(buf)
        end if
        ! exponent form, tidied: 2.5E-005 -> 2.5e-5
        text = buf(1:e - 1)
        if (index(text, '.') == len(text)) text = text // '0'
        text = text // 'e' // itoa(ex)
    end function real_text

    function reals_text(x) result(text)
        real(wp), intent(in) :: x(:)
        character(len=:), allocatable :: text
        integer :: k
        text = ''
        do k = 1, size(x)
            if (k > 1) text = text // ', '
            text = text // real_text(x(k))
        end do
    end function reals_text

    function range_text(min, max, min_exclusive, max_exclusive) result(text)
        real(wp), intent(in), optional :: min, max, min_exclusive, max_exclusive
        character(len=:), allocatable :: text
        text = ''
        if (present(min)) text = '>= ' // real_text(min)
        if (present(min_exclusive)) text = '> ' // real_text(min_exclusive)
        if (present(max) .or. present(max_exclusive)) then
            if (len(text) > 0) text = text // ' and '
            if (present(max)) text = text // '<= ' // real_text(max)
            if (present(max_exclusive)) text = text // '< ' // real_text(max_exclusive)
        end if
    end function range_text

    function unit_suffix(unit) result(text)
        character(len=*), intent(in), optional :: unit
        character(len=:), allocatable :: text
        text = ''
        if (present(unit)) then
            if (len(unit) > 0) text = ' (' // unit // ')'
        end if
    end function unit_suffix

    function logical_text(x) result(text)
        logical, intent(in) :: x
        character(len=:), allocatable :: text
        text = merge('.true. ', '.false.', x)
        text = trim(text)
    end function logical_text

    !> A quoted string, inner quotes doubled.
    function quote(s) result(text)
        character(len=*), intent(in) :: s
        character(len=:), allocatable :: text
        integer :: k
        text = "'"
        do k = 1, len(s)
            if (s(k:k) == "'") text = text // "'"
            text = text // s(k:k)
        end do
        text = text // "'"
    end function quote

    !> "; did you mean 'x'?" for the closest name within a small edit distance, else '.'
    !> (the end of the sentence either way).
    function suggestion(name, names) result(text)
        character(len=*), intent(in) :: name
        character(len=*), intent(in) :: names(:)
        character(len=:), allocatable :: text
        integer :: k, best, dist, best_k
        text = ''
        best = huge(1)
        best_k = 0
        do k = 1, size(names)
            dist = edit_distance(name, trim(names(k)))
            if (dist < best) then
                best = dist
                best_k = k
            end if
        end do
        if (best_k > 0 .and. best <= max(1, len(name) / 3)) &
            text = "; did you mean '" // trim(names(best_k)) // "'?"
        if (len(text) == 0) text = '.'
    end function suggestion

    pure integer function edit_distance(a, b) result(dist)
        character(len=*), intent(in) :: a, b
        integer :: row(0:len(b)), prev, tmp, i, j
        row = [(j, j = 0, len(b))]
        do i = 1, len(a)
            prev = row(0)
            row(0) = i
            do j = 1, len(b)
                tmp = row(j)
                row(j) = min(row(j) + 1, row(j - 1) + 1, &
                    prev + merge(0, 1, a(i:i) == b(j:j)))
                prev = tmp
            end do
        end do
        dist = row(len(b))
    end function edit_distance

    function join(names, sep, lead) result(text)
        character(len=*), intent(in) :: names(:), sep, lead
        character(len=:), allocatable :: text
        integer :: k
        text = lead
        do k = 1, size(names)
            if (k > 1) text = text // sep
            text = text // trim(names(k))
        end do
    end function join

    function join_ints(v) result(text)
        integer, intent(in) :: v(:)
        character(len=:), allocatable :: text
        integer :: k
        text = ''
        do k = 1, size(v)
            if (k > 1) text = text // ','
            text = text // itoa(v(k))
        end do
    end function join_ints

    subroutine split_commas(text, parts)
        character(len=*), intent(in) :: text
        character(len=:), allocatable, intent(out) :: parts(:)
        integer :: n, k, start, c
        n = 1
        do k = 1, len(text)
            if (text(k:k) == ',') n = n + 1
        end do
        allocate(character(len=max(len(text), 1)) :: parts(n))
        start = 1
        do k = 1, n
            c = index(text(start:), ',')
            if (c == 0) then
                parts(k) = text(start:)
            else
                parts(k) = text(start:start + c - 2)
                start = start + c
            end if
        end do
    end subroutine split_commas

end module sph_namelist
