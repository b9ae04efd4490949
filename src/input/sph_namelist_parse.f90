!> The namelist parser (sph_namelist's nml_parse): text into groups of assignments, with the
!> syntax errors named by source, line and group; and the text helpers it shares with the
!> module (itoa, printable, to_lower, is_name). A submodule of sph_namelist, whose typed
!> getters, checks and messages read what it builds.
submodule (sph_namelist) sph_namelist_parse
    implicit none

contains

    module procedure nml_parse
        integer :: pos, line, n_groups
        character(len=:), allocatable :: tok, pending_key, pending_sub
        integer :: kind_tok, tok_line, open_line
        logical :: quoted, in_group, expect_value, after_value, repeat_quoted
        integer :: key_line
        ! the line of the last group's end and whether an unquoted value came right before it
        integer :: end_line
        logical :: end_after_unquoted
        type(nml_group_t) :: grp
        ! the pending key's values, values(1:n_values) (grown by doubling: appended one by
        ! one, 20000 values took 20 s)
        type(nml_value_t), allocatable :: values(:)
        integer :: n_values
        type(nml_group_t), allocatable :: groups(:)
        integer, parameter :: t_eof = 0, t_group = 1, t_end = 2, t_name = 3, t_value = 4, &
            t_comma = 5
        character(len=:), allocatable :: text

        stat = 0
        text = lines_ended_by_nl(raw_text)
        errmsg = ''
        file%source = source
        allocate(groups(0))
        pos = 1
        line = 1
        in_group = .false.
        expect_value = .false.
        allocate(values(16))
        n_values = 0
        end_line = 0
        end_after_unquoted = .false.
        n_groups = 0
        open_line = 0
        ! a UTF-8 byte-order mark, as some editors write it, is not part of the text; UTF-16
        ! (a byte-order mark of its own, or NUL bytes) is not ASCII-compatible at all
        if (len(text) >= 3) then
            if (text(1:3) == achar(239) // achar(187) // achar(191)) pos = 4
        end if
        if (index(text, achar(0)) > 0 .or. index(text, achar(254) // achar(255)) == 1 .or. &
            index(text, achar(255) // achar(254)) == 1) then
            call fail(1, 'not a plain text file (NUL bytes or a UTF-16 byte-order mark): ' // &
                'save it as UTF-8 or ASCII text')
            return
        end if
        do
            call next_token(kind_tok, tok, quoted, tok_line)
            if (stat /= 0) return
            if (.not. in_group) then
                select case (kind_tok)
                case (t_eof)
                    exit
                case (t_group)
                    grp = nml_group_t(name=tok, line=tok_line)
                    allocate(grp%items(0), grp%keys(0))
                    grp%resolved = ''
                    grp%errors = ''
                    grp%notes = ''
                    in_group = .true.
                    open_line = tok_line
                case (t_end)
                    call fail(tok_line, "a group's end ('/' or &end) outside a group (one " // &
                        "closed twice, or text after a group's end)" // slash_hint())
                    return
                case default
                    call fail(tok_line, "text outside a group: '" // tok // "'" // slash_hint())
                    return
                end select
                cycle
            end if
            select case (kind_tok)
            case (t_eof)
                call fail(open_line, 'group &' // grp%name // ' is not closed by / ' // &
                    '(truncated file?)')
                return
            case (t_group)
                call fail(tok_line, 'group &' // tok // ' starts inside &' // grp%name // &
                    ' (opened on line ' // itoa(open_line) // '), which is not closed by /')
                return
            case (t_end)
                ! (an unquoted value right before it: 'output_dir = output/run1' ends the
                ! group at its '/', and the rest reads as text outside a group)
                end_line = tok_line
                end_after_unquoted = .false.
                if (expect_value .and. after_value .and. n_values > 0) &
                    end_after_unquoted = .not. values(n_values)%quoted
                if (expect_value) call store()
                expect_value = .false.
                groups = [groups, grp]
                in_group = .false.
            case (t_name)
                if (expect_value) call store()
                call split_key(tok, pending_key, pending_sub)
                if (stat /= 0) return
                n_values = 0
                expect_value = .true.
                after_value = .false.
                key_line = tok_line
            case (t_comma)
                if (.not. expect_value) then
                    call fail(tok_line, 'stray comma in &' // grp%name)
                    return
                end if
                ! a comma after a value only separates; one after '=' or a comma is a null
                if (.not. after_value) call push(nml_value_t(text='', null=.true., &
                    line=tok_line))
                after_value = .false.
            case (t_value)
                if (.not. expect_value) then
                    ! a name here is a key whose '=' is missing ('key (2) 0.0', 'key 1.0')
                    if (.not. quoted .and. is_name(tok)) then
                        call fail(tok_line, "'" // tok // "' in &" // grp%name // &
                            " is not followed by '=' (expected key = value)")
                    else
                        call fail(tok_line, "value '" // tok // "' in &" // grp%name // &
                            ' has no key (expected key = value)')
                    end if
                    return
                end if
                call add_value(tok, quoted, tok_line)
                if (stat /= 0) return
                after_value = .true.
            end select
        end do
        file%groups = groups

    contains

        subroutine store()
            type(nml_item_t) :: item
            ! `key =` with nothing after it (a new key or '/' next) is a null value, as
            ! `key = ,` is: the key keeps its default (an integer or logical key said
            ! 'expects one value, got 0')
            if (n_values == 0) call push(nml_value_t(text='', null=.true., line=key_line))
            item%values = values(1:n_values)
            item%key = pending_key
            item%subscript = pending_sub
            item%line = key_line
            grp%items = [grp%items, item]
            n_values = 0
        end subroutine store

        subroutine add_value(token, is_quoted, at_line)
            character(len=*), intent(in) :: token
            logical, intent(in) :: is_quoted
            integer, intent(in) :: at_line
            integer, parameter :: MAX_REPEAT = 100000
            integer :: star, count, ios, k
            character(len=:), allocatable :: rest
            star = 0
            if (.not. is_quoted) star = index(token, '*')
            if (star > 1 .and. verify(token(1:star - 1), '0123456789') == 0) then
                read(token(1:star - 1), *, iostat=ios) count
                if (ios /= 0 .or. count < 1) then
                    call fail(at_line, "bad repeat count in '" // token // "'")
                    return
                end if
                ! no key takes more values than this; a larger count is a typo
                if (count > MAX_REPEAT) then
                    call fail(at_line, "repeat count in '" // token // "' above " // &
                        itoa(MAX_REPEAT) // ' (more values than any key takes)')
                    return
                end if
                rest = token(star + 1:)
                ! (a list-directed read of the value would take '2*0.3' as a second count)
                if (.not. repeat_quoted .and. index(rest, '*') > 0) then
                    call fail(at_line, "a repeat count inside a repeat in '" // token // "'")
                    return
                end if
                ! appended at once (appended one by one, 20000* took 9 s)
                do k = 1, count
                    call push(nml_value_t(text=rest, quoted=repeat_quoted, &
                        null=len(rest) == 0 .and. .not. repeat_quoted, line=at_line))
                end do
            else
                call push(nml_value_t(text=token, quoted=is_quoted, line=at_line))
            end if
        end subroutine add_value

        !> For text found after a group's end on that end's line, when an unquoted value
        !> came right before the end: the '/' was most likely part of the value.
        function slash_hint() result(text)
            character(len=:), allocatable :: text
            text = ''
            if (end_after_unquoted .and. tok_line == end_line) text = ' (a / in an ' // &
                "unquoted value ends its group: quote strings, 'output/run1')"
        end function slash_hint

        !> Append one value to the pending key's.
        subroutine push(value)
            type(nml_value_t), intent(in) :: value
            type(nml_value_t), allocatable :: grown(:)
            if (n_values == size(values)) then
                allocate(grown(2 * size(values)))
                grown(1:n_values) = values(1:n_values)
                call move_alloc(grown, values)
            end if
            n_values = n_values + 1
            values(n_values) = value
        end subroutine push

        subroutine split_key(token, key, sub)
            character(len=*), intent(in) :: token
            character(len=:), allocatable, intent(out) :: key, sub
            integer :: p
            p = index(token, '(')
            if (p == 0) then
                key = to_lower(token)
                sub = ''
            else
                key = to_lower(token(1:p - 1))
                if (token(len(token):len(token)) /= ')') then
                    call fail(tok_line, "bad subscript in '" // token // "'")
                    return
                end if
                sub = token(p + 1:len(token) - 1)
                ! ('key()' read as the whole array)
                if (len_trim(sub) == 0) then
                    call fail(tok_line, "empty subscript in '" // token // "'")
                    return
                end if
            end if
            if (len(key) == 0 .or. verify(key, name_chars) /= 0) &
                call fail(tok_line, "bad key name '" // token // "' in &" // grp%name)
        end subroutine split_key

        subroutine fail(at_line, what)
            integer, intent(in) :: at_line
            character(len=*), intent(in) :: what
            stat = 1
            errmsg = source // ':' // itoa(at_line) // ': ' // printable(what)
        end subroutine fail

        !> The next token: a group start (&name), an end (/ or &end), a key (name or name(..)
        !> followed by =), a comma, or a value (bare token or quoted string).
        subroutine next_token(kind_out, token, is_quoted, at_line)
            integer, intent(out) :: kind_out
            character(len=:), allocatable, intent(out) :: token
            logical, intent(out) :: is_quoted
            integer, intent(out) :: at_line
            integer :: start, depth, p, lines
            character(len=1) :: ch
            is_quoted = .false.
            repeat_quoted = .false.
            token = ''
            call skip_blanks(pos, lines)
            line = line + lines
            if (pos > len(text)) then
                kind_out = t_eof
                at_line = line
                return
            end if
            ch = text(pos:pos)
            at_line = line
            if (ch == '&' .or. ch == '$') then
                start = pos + 1
                pos = start
                do while (pos <= len(text))
                    if (verify(text(pos:pos), name_chars) /= 0) exit
                    pos = pos + 1
                end do
                token = to_lower(text(start:pos - 1))
                if (token == 'end') then
                    kind_out = t_end
                else if (len(token) == 0) then
                    call fail(line, "'" // ch // "' without a group name")
                else
                    kind_out = t_group
                end if
                return
            end if
            if (ch == '/') then
                pos = pos + 1
                kind_out = t_end
                return
            end if
            if (ch == ',' .or. ch == ';') then
                pos = pos + 1
                kind_out = t_comma
                return
            end if
            kind_out = t_value
            if (ch == '"' .or. ch == "'") then
                call read_string(token)
                is_quoted = .true.
                return
            end if
            start = pos
            depth = 0
            do while (pos <= len(text))
                ch = text(pos:pos)
                if (ch == '(') depth = depth + 1
                if (ch == ')') depth = depth - 1
                ! a subscript holds neither ')' first nor '=' nor a new line: a stray
                ! parenthesis would otherwise swallow the rest of the file
                if (depth < 0 .or. (depth > 0 .and. (ch == '=' .or. ch == nl))) then
                    if (pos == start) then
                        call fail(line, "a ')' without a '(' before it")
                    else
                        call fail(line, "unbalanced parentheses in '" // &
                            text(start:pos - 1) // "'")
                    end if
                    return
                end if
                if (depth == 0) then
                    if (index(' ,;/=!' // nl // achar(9) // achar(13), ch) > 0) exit
                    if ((ch == '"' .or. ch == "'") .and. pos > start) then
                        if (text(pos - 1:pos - 1) == '*') exit
                    end if
                end if
                pos = pos + 1
            end do
            token = text(start:pos - 1)
            ! (every other separator was skipped above: an empty token is a stray '=')
            if (len(token) == 0) then
                call fail(line, "'=' without a key before it")
                return
            end if
            if (pos <= len(text)) then
                ch = text(pos:pos)
                if ((ch == '"' .or. ch == "'") .and. token(len(token):len(token)) == '*') then
                    block
                        character(len=:), allocatable :: str
                        call read_string(str)
                        token = token // str
                        repeat_quoted = .true.
                    end block
                    return
                end if
            end if
            ! a key is a name followed by '='
            p = pos
            do while (p <= len(text))
                if (text(p:p) /= ' ' .and. text(p:p) /= achar(9)) exit
                p = p + 1
            end do
            ! `key (i) =`: blanks before a subscript, as Fortran's own namelist read takes them
            if (p > pos .and. p <= len(text) .and. verify(token, name_chars) == 0) then
                if (text(p:p) == '(') call join_subscript(token, p)
            end if
            if (p <= len(text)) then
                if (text(p:p) == '=') then
                    kind_out = t_name
                    pos = p + 1
                    return
                end if
            end if
            ! a name (with its subscript or not) whose '=' starts a later line (comments
            ! between), as Fortran's own namelist read takes it (it was read as a value of
            ! the key before)
            if (is_name(token)) then
                call equals_on_later_line(kind_out)
            else if (index(token, '(') > 1) then
                if (token(len(token):len(token)) == ')' .and. &
                    is_name(token(1:index(token, '(') - 1))) call equals_on_later_line(kind_out)
            end if
        end subroutine next_token

        !> After a name token ending at pos: when only blanks, line ends and comments come
        !> before an '=', the token is a key: pos moves past the '=', line counts the lines.
        subroutine equals_on_later_line(kind_out)
            integer, intent(inout) :: kind_out
            integer :: q, lines
            q = pos
            call skip_blanks(q, lines)
            if (lines == 0 .or. q > len(text)) return
            if (text(q:q) /= '=') return
            kind_out = t_name
            line = line + lines
            pos = q + 1
        end subroutine equals_on_later_line

        !> q moved past blanks (spaces, tabs, carriage returns), line ends and comments, to
        !> the next character that means something or past the end; lines: the line ends
        !> passed.
        subroutine skip_blanks(q, lines)
            integer, intent(inout) :: q
            integer, intent(out) :: lines
            character(len=1) :: ch
            lines = 0
            do while (q <= len(text))
                ch = text(q:q)
                if (ch == nl) then
                    lines = lines + 1
                    q = q + 1
                else if (ch == ' ' .or. ch == achar(9) .or. ch == achar(13)) then
                    q = q + 1
                else if (ch == '!') then
                    do while (q <= len(text))
                        if (text(q:q) == nl) exit
                        q = q + 1
                    end do
                else
                    exit
                end if
            end do
        end subroutine skip_blanks

        !> The subscript at text(p:) joined to the key token when '=' follows it (on its
        !> line, or after blank and comment lines: `body_force (1)` then `= 2e-4` on the next
        !> was refused, fz48); p left at that '=', line counting the lines passed. Otherwise
        !> token and p are left as they were.
        subroutine join_subscript(token, p)
            character(len=:), allocatable, intent(inout) :: token
            integer, intent(inout) :: p
            integer :: q, r, lines
            q = index(text(p:), ')')
            if (q == 0) return
            q = p + q - 1
            if (scan(text(p:q), '=' // nl) > 0) return
            r = q + 1
            call skip_blanks(r, lines)
            if (r > len(text)) return
            if (text(r:r) /= '=') return
            token = token // text(p:q)
            p = r
            line = line + lines
        end subroutine join_subscript

        subroutine read_string(str)
            character(len=:), allocatable, intent(out) :: str
            character(len=1) :: q
            integer :: start_line
            q = text(pos:pos)
            start_line = line
            str = ''
            pos = pos + 1
            do
                if (pos > len(text)) then
                    call fail(start_line, 'string not closed by ' // q // ' in &' // grp%name)
                    return
                end if
                if (text(pos:pos) == q) then
                    if (pos < len(text)) then
                        if (text(pos + 1:pos + 1) == q) then   ! doubled quote
                            str = str // q
                            pos = pos + 2
                            cycle
                        end if
                    end if
                    pos = pos + 1
                    exit
                end if
                if (text(pos:pos) == nl) then   ! no key holds a line break: a missing quote
                    call fail(start_line, 'string not closed by ' // q // &
                        ' on its line in &' // grp%name)
                    return
                end if
                if (text(pos:pos) /= achar(13)) str = str // text(pos:pos)
                pos = pos + 1
            end do
        end subroutine read_string
    end procedure nml_parse

    !> text with every line ended by a new line character: a carriage return not followed
    !> by one (old Mac files) ends a line too; CR LF (Windows) is left to the blank skipping.
    pure function lines_ended_by_nl(text) result(out)
        character(len=*), intent(in) :: text
        character(len=len(text)) :: out
        integer :: k
        out = text
        do k = 1, len(text)
            if (text(k:k) /= achar(13)) cycle
            if (k < len(text)) then
                if (text(k + 1:k + 1) == nl) cycle
            end if
            out(k:k) = nl
        end do
    end function lines_ended_by_nl

    module procedure itoa
        character(len=16) :: buf
        write(buf, '(i0)') i
        text = trim(buf)
    end procedure itoa

    module procedure printable
        character(len=*), parameter :: hex = '0123456789abcdef'
        integer :: k, code
        shown = ''
        do k = 1, len(text)
            code = iachar(text(k:k))
            if (code >= 32 .and. code <= 126) then
                shown = shown // text(k:k)
            else
                shown = shown // '\x' // hex(code / 16 + 1:code / 16 + 1) // &
                    hex(mod(code, 16) + 1:mod(code, 16) + 1)
            end if
        end do
    end procedure printable

    module procedure to_lower
        integer :: k
        out = s
        do k = 1, len(s)
            if (s(k:k) >= 'A' .and. s(k:k) <= 'Z') out(k:k) = achar(iachar(s(k:k)) + 32)
        end do
    end procedure to_lower

    module procedure is_name
        yes = len(token) > 0
        if (.not. yes) return
        yes = verify(token(1:1), name_chars(1:52)) == 0 .and. verify(token, name_chars(1:63)) == 0
    end procedure is_name
end submodule sph_namelist_parse
