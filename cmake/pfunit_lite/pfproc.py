#!/usr/bin/env python3
"""pfunit_lite: the project's small runner for pFUnit 4 test files (.pf).

It implements the subset of pFUnit 4 the project's tests use (see tests/README.md) with the
same meaning, so the same .pf files build with real pFUnit on clusters and with this runner
everywhere else.

  pfproc.py test FILE.pf OUT_MODULE.F90 OUT_DRIVER.F90   # a test file -> module + driver
  pfproc.py support OUT_DIR                              # the Fortran support library

The test module is the .pf with every annotation replaced in place (line numbers kept):
  @test / @test(npes=[1,2]) / @before / @after  -> comments (recorded for the driver)
  @assertX(args)  -> call pf_assert_x(args, file=, line=); if (pf_failed()) return
which matches real pFUnit, whose preprocessor also returns from the test after a failed
assertion. The driver runs every test (once per listed process count for MPI tests, on a
fresh sub-communicator of that size), prints each failure with file:line, expected, actual
and difference (and the rank), closes with 'N passed, N failed' and exits non-zero if any
test failed.
"""
import os
import re
import sys

ASSERTIONS = {
    "assertequal": "pf_assert_equal",
    "assertrelativelyequal": "pf_assert_relatively_equal",
    "assertlessthan": "pf_assert_less_than",
    "assertlessthanorequal": "pf_assert_less_than_or_equal",
    "assertgreaterthan": "pf_assert_greater_than",
    "assertgreaterthanorequal": "pf_assert_greater_than_or_equal",
    "asserttrue": "pf_assert_true",
    "assertfalse": "pf_assert_false",
    "assertisfinite": "pf_assert_is_finite",
}
# positional roles after the compared values, per assertion (pFUnit's argument order)
ROLES = {
    "pf_assert_equal": (["expected", "actual"], ["tolerance", "message"]),
    "pf_assert_relatively_equal": (["expected", "actual", "tolerance"], ["message"]),
    "pf_assert_less_than": (["a", "b"], ["message"]),
    "pf_assert_less_than_or_equal": (["a", "b"], ["message"]),
    "pf_assert_greater_than": (["a", "b"], ["message"]),
    "pf_assert_greater_than_or_equal": (["a", "b"], ["message"]),
    "pf_assert_true": (["condition"], ["message"]),
    "pf_assert_false": (["condition"], ["message"]),
    "pf_assert_is_finite": (["x"], ["message"]),
}


class PfError(Exception):
    pass


def split_top_level(text):
    """Split at commas outside parentheses, brackets and strings."""
    parts, depth, quote, current = [], 0, None, []
    for ch in text:
        if quote:
            current.append(ch)
            if ch == quote:
                quote = None
            continue
        if ch in "'\"":
            quote = ch
        elif ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(current).strip())
            current = []
            continue
        current.append(ch)
    tail = "".join(current).strip()
    if tail:
        parts.append(tail)
    return parts


def balanced_arguments(line, start):
    """Text between the parenthesis at `start` and its partner, and the rest of the line."""
    depth, quote = 0, None
    for i in range(start, len(line)):
        ch = line[i]
        if quote:
            if ch == quote:
                quote = None
            continue
        if ch in "'\"":
            quote = ch
        elif ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
            if depth == 0:
                return line[start + 1:i], line[i + 1:]
    raise PfError("unbalanced parentheses (an assertion must fit on one line)")


KEYWORD = re.compile(r"^([A-Za-z_]\w*)\s*=(?![=>])(.*)$", re.S)


def looks_like_message(arg):
    """A positional argument that is a character expression: a literal or a concatenation."""
    stripped = arg.strip()
    return stripped[:1] in "'\"" or "//" in stripped or stripped.lower().startswith("trim(")


def assertion_call(name, args_text, source, line_number):
    procedure = ASSERTIONS[name.lower()]
    required, optional = ROLES[procedure]
    args = split_top_level(args_text)
    positional, keywords = [], {}
    for arg in args:
        match = KEYWORD.match(arg)
        if match and match.group(1).lower() in ("tolerance", "message", "expected", "actual",
                                                "found", "condition"):
            key = match.group(1).lower()
            keywords["actual" if key == "found" else key] = match.group(2).strip()
        else:
            if keywords:
                raise PfError("positional argument after a keyword argument")
            positional.append(arg)
    if len(positional) < len(required) - sum(1 for r in required if r in keywords):
        raise PfError(f"@{name} needs at least {len(required)} arguments")
    if procedure in ("pf_assert_less_than", "pf_assert_less_than_or_equal", "pf_assert_greater_than",
                     "pf_assert_greater_than_or_equal") and len(positional) > 2:
        # real pFUnit: integer comparisons put a KeywordEnforcer before the message and real
        # ones take a tolerance there; only message= means the same in both
        raise PfError(f"@{name}: give the message as message='...' (portable to real pFUnit)")
    out = []
    values = positional[:len(required)]
    rest = positional[len(required):]
    out.extend(values)
    # pFUnit: assertEqual(expected, actual[, tolerance][, message]); a lone third argument
    # that is a character expression is the message
    if procedure == "pf_assert_equal" and len(rest) == 1 and looks_like_message(rest[0]):
        keywords.setdefault("message", rest[0])
    else:
        for role, value in zip(optional, rest):
            keywords.setdefault(role, value)
        if len(rest) > len(optional):
            raise PfError(f"@{name}: too many arguments")
    for role in ("expected", "actual", "condition"):
        if role in keywords:
            out.append(f"{role}={keywords.pop(role)}")
    for role in ("tolerance", "message"):
        if role in keywords:
            out.append(f"{role}={keywords.pop(role)}")
    out.append(f"file='{os.path.basename(source)}'")
    out.append(f"line={line_number}")
    return f"call {procedure}({', '.join(out)}); if (pf_failed()) return"


ANNOTATION = re.compile(r"^\s*@(\w+)\s*(\((.*)\))?\s*(!.*)?$", re.I)
SUBROUTINE = re.compile(r"^\s*(?:(?:pure|recursive|impure|module)\s+)*subroutine\s+(\w+)\s*(\(([^)]*)\))?",
                        re.I)
MODULE = re.compile(r"^\s*module\s+(\w+)\s*(!.*)?$", re.I)
USE_PFUNIT = re.compile(r"^\s*use\s+pfunit\b", re.I)


def parse_npes(options):
    if not options:
        return None
    match = re.search(r"npes\s*=\s*\[([^\]]*)\]", options, re.I)
    if not match:
        return None
    values = [int(v) for v in match.group(1).replace(" ", "").split(",") if v]
    if not values:
        raise PfError("@test(npes=[...]) lists no process counts")
    return values


def process(source):
    with open(source, encoding="utf-8") as handle:
        lines = handle.read().split("\n")
    out, tests, before, after = [], [], None, None
    pending, module, mpi = None, None, False
    for number, line in enumerate(lines, start=1):
        try:
            stripped = line.strip()
            if MODULE.match(line) and module is None:
                module = MODULE.match(line).group(1)
            if USE_PFUNIT.match(line):
                mpi = True
            if stripped.startswith("@"):
                name = re.match(r"@(\w+)", stripped).group(1)
                if name.lower() in ASSERTIONS:
                    start = stripped.index("(")
                    args_text, rest = balanced_arguments(stripped, start)
                    if rest.strip() and not rest.strip().startswith("!"):
                        raise PfError(f"unexpected text after @{name}(...)")
                    indent = line[:len(line) - len(line.lstrip())]
                    out.append(indent + assertion_call(name, args_text, source, number))
                    continue
                match = ANNOTATION.match(line)
                if not match:
                    raise PfError(f"cannot read annotation '{stripped}'")
                kind = match.group(1).lower()
                if kind == "test":
                    pending = ("test", parse_npes(match.group(3)))
                elif kind == "before":
                    pending = ("before", None)
                elif kind == "after":
                    pending = ("after", None)
                else:
                    raise PfError(f"annotation @{match.group(1)} is not in the supported subset")
                out.append("!" + line)
                continue
            if pending:
                sub = SUBROUTINE.match(line)
                if sub:
                    args = [a.strip() for a in (sub.group(3) or "").split(",") if a.strip()]
                    kind, npes = pending
                    entry = {"name": sub.group(1), "takes_this": len(args) == 1, "npes": npes,
                             "line": number}
                    if kind == "test":
                        if npes is not None and not entry["takes_this"]:
                            raise PfError(f"MPI test {sub.group(1)} must take (this)")
                        if npes is None and entry["takes_this"]:
                            entry["npes"] = [1]
                        tests.append(entry)
                    elif kind == "before":
                        before = entry
                    else:
                        after = entry
                    pending = None
                elif stripped and not stripped.startswith("!"):
                    raise PfError("an annotation must be followed by a subroutine")
            out.append(line)
        except PfError as problem:
            raise PfError(f"{source}:{number}: {problem}") from None
    base = os.path.splitext(os.path.basename(source))[0]
    if module is None or module.lower() != base.lower():
        raise PfError(f"{source}: the module must be named after the file ({base})")
    if not tests:
        raise PfError(f"{source}: no @test found")
    if any(t["npes"] for t in tests) and not mpi:
        raise PfError(f"{source}: MPI tests need 'use pfunit'")
    return "\n".join(out), module, tests, before, after, mpi


def driver_source(source, module, tests, before, after, mpi):
    base = os.path.basename(source)
    body = []
    if not mpi:
        body.append(f"    call pf_begin('{base}')")
        for test in tests:
            body.append(f"    call pf_start('{test['name']}')")
            if before:
                body.append(f"    call {before['name']}()")
            body.append(f"    call {test['name']}()")
            if after:
                body.append(f"    call {after['name']}()")
            body.append("    call pf_finish()")
        body.append("    call pf_end()")
        return (f"! generated by pfproc.py from {base}: do not edit\n"
                f"program {module}_driver\n    use pfunit_lite_core\n    use {module}\n"
                "    implicit none\n" + "\n".join(body) + f"\nend program {module}_driver\n")
    body.append(f"    call pf_mpi_begin('{base}')")
    for test in tests:
        for npes in test["npes"]:
            body.append(f"    if (pf_mpi_start('{test['name']}', {npes}, this)) then")
            if before:
                body.append(f"        call {before['name']}({'this' if before['takes_this'] else ''})")
            body.append(f"        call {test['name']}(this)")
            if after:
                body.append(f"        call {after['name']}({'this' if after['takes_this'] else ''})")
            body.append("    end if")
            body.append("    call pf_mpi_finish(this)")
    body.append("    call pf_mpi_end()")
    return (f"! generated by pfproc.py from {base}: do not edit\n"
            f"program {module}_driver\n    use pfunit\n    use {module}\n    implicit none\n"
            "    type(MpiTestMethod) :: this\n" + "\n".join(body) + f"\nend program {module}_driver\n")


# ---------------------------------------------------------------------------------------
# Fortran support library, generated so that every type and rank gets its specific
# procedure without hand-copied code.
# ---------------------------------------------------------------------------------------
TYPES = {  # key: (declaration, format for one value, numeric)
    "int": ("integer", "(i0)", True),
    "i8": ("integer(int64)", "(i0)", True),
    "r64": ("real(real64)", "(es24.16)", True),
    "r32": ("real(real32)", "(es15.7)", True),
    "log": ("logical", "(l1)", False),
    "chr": ("character(len=*)", "(a)", False),
}


def dims(rank):
    return "" if rank == 0 else "(" + ", ".join([":"] * rank) + ")"


def support_core():
    return r'''! generated by pfproc.py support: do not edit
!> Bookkeeping of the pfunit_lite runner: the current test, its failures, the summary.
module pfunit_lite_core
    use, intrinsic :: iso_fortran_env, only: output_unit, int64, real32, real64
    use, intrinsic :: iso_c_binding, only: c_int
    implicit none
    private
    public :: pf_begin, pf_start, pf_finish, pf_end, pf_failed, pf_fail, pf_set_rank
    public :: pf_counts, pf_current_failed, pf_reset_current, pf_exit, pf_file_name
    public :: pf_format

    character(len=256), save :: file_name = ''
    character(len=256), save :: test_name = ''
    integer, save :: n_passed = 0, n_failed = 0
    logical, save :: current_failed = .false.
    integer, save :: my_rank = -1

    interface
        subroutine c_exit(status) bind(C, name="exit")
            import :: c_int
            integer(c_int), value :: status
        end subroutine c_exit
    end interface

    interface pf_format
        module procedure format_int, format_i8, format_r64, format_r32, format_log, format_chr
    end interface

contains

    subroutine pf_begin(name)
        character(len=*), intent(in) :: name
        file_name = name
        n_passed = 0
        n_failed = 0
    end subroutine pf_begin

    function pf_file_name() result(name)
        character(len=:), allocatable :: name
        name = trim(file_name)
    end function pf_file_name

    subroutine pf_set_rank(rank)
        integer, intent(in) :: rank
        my_rank = rank
    end subroutine pf_set_rank

    subroutine pf_start(name)
        character(len=*), intent(in) :: name
        test_name = name
        current_failed = .false.
    end subroutine pf_start

    subroutine pf_reset_current()
        current_failed = .false.
    end subroutine pf_reset_current

    logical function pf_current_failed()
        pf_current_failed = current_failed
    end function pf_current_failed

    !> Serial: count the test that just ran and report it.
    subroutine pf_finish()
        if (current_failed) then
            n_failed = n_failed + 1
            write(output_unit, '(a)') 'FAILED  ' // trim(test_name)
        else
            n_passed = n_passed + 1
            write(output_unit, '(a)') 'passed  ' // trim(test_name)
        end if
        flush(output_unit)
    end subroutine pf_finish

    subroutine pf_counts(passed, failed, add_passed, add_failed)
        integer, intent(out) :: passed, failed
        integer, intent(in) :: add_passed, add_failed
        n_passed = n_passed + add_passed
        n_failed = n_failed + add_failed
        passed = n_passed
        failed = n_failed
    end subroutine pf_counts

    subroutine pf_end()
        write(output_unit, '(i0,a,i0,a)') n_passed, ' passed, ', n_failed, ' failed'
        flush(output_unit)
        call pf_exit(merge(1, 0, n_failed > 0))
    end subroutine pf_end

    subroutine pf_exit(status)
        integer, intent(in) :: status
        flush(output_unit)
        call c_exit(int(status, c_int))
    end subroutine pf_exit

    logical function pf_failed()
        pf_failed = current_failed
    end function pf_failed

    !> Record a failure: where, what was expected, what was found and by how much.
    subroutine pf_fail(file, line, what, message, expected, actual, difference)
        character(len=*), intent(in) :: file, what
        integer, intent(in) :: line
        character(len=*), intent(in), optional :: message, expected, actual, difference
        character(len=32) :: where
        current_failed = .true.
        write(where, '(a,i0)') ':', line
        if (my_rank >= 0) then
            write(output_unit, '(a,i0,a)') 'FAILURE in ' // trim(test_name) // ' (rank ', my_rank, &
                ') at ' // trim(file) // trim(where) // ': ' // what
        else
            write(output_unit, '(a)') 'FAILURE in ' // trim(test_name) // ' at ' // trim(file) // &
                trim(where) // ': ' // what
        end if
        if (present(message)) write(output_unit, '(a)') '    message:    ' // message
        if (present(expected)) write(output_unit, '(a)') '    expected:   ' // expected
        if (present(actual)) write(output_unit, '(a)') '    actual:     ' // actual
        if (present(difference)) write(output_unit, '(a)') '    difference: ' // difference
        flush(output_unit)
    end subroutine pf_fail

    function format_int(x) result(s)
        integer, intent(in) :: x
        character(len=:), allocatable :: s
        character(len=64) :: b
        write(b, '(i0)') x
        s = trim(b)
    end function format_int

    function format_i8(x) result(s)
        integer(int64), intent(in) :: x
        character(len=:), allocatable :: s
        character(len=64) :: b
        write(b, '(i0)') x
        s = trim(b)
    end function format_i8

    function format_r64(x) result(s)
        real(real64), intent(in) :: x
        character(len=:), allocatable :: s
        character(len=64) :: b
        write(b, '(es24.16)') x
        s = trim(adjustl(b))
    end function format_r64

    function format_r32(x) result(s)
        real(real32), intent(in) :: x
        character(len=:), allocatable :: s
        character(len=64) :: b
        write(b, '(es15.7)') x
        s = trim(adjustl(b))
    end function format_r32

    function format_log(x) result(s)
        logical, intent(in) :: x
        character(len=:), allocatable :: s
        s = merge('.true. ', '.false.', x)
        s = trim(s)
    end function format_log

    function format_chr(x) result(s)
        character(len=*), intent(in) :: x
        character(len=:), allocatable :: s
        s = '"' // x // '"'
    end function format_chr
end module pfunit_lite_core
'''


def equal_specific(key, rank_e, rank_a):
    """assertEqual for one type, expected rank and actual rank (expected scalar or same rank)."""
    decl, _, numeric = TYPES[key]
    name = f"equal_{key}_{rank_e}{rank_a}"
    real = key in ("r64", "r32")
    kind = "real64" if key == "r64" else "real32"
    tol_decl = f"        real({kind}), intent(in), optional :: tolerance\n" if real else ""
    tol_arg = "tolerance, " if real else ""
    lines = [f"    subroutine {name}(expected, actual, {tol_arg}message, file, line)",
             f"        {decl}, intent(in) :: expected{dims(rank_e)}",
             f"        {decl}, intent(in) :: actual{dims(rank_a)}",
             tol_decl.rstrip("\n") if tol_decl else None,
             "        character(len=*), intent(in), optional :: message",
             "        character(len=*), intent(in) :: file",
             "        integer, intent(in) :: line"]
    if real:
        lines.append(f"        real({kind}) :: tol")
    lines = [l for l in lines if l is not None]
    if rank_a > 0:
        lines.append("        integer :: i" + (", j" if rank_a == 2 else ""))
        lines.append("        character(len=64) :: at")
    if real:
        lines.append(f"        tol = 0.0_{kind}")
        lines.append("        if (present(tolerance)) tol = tolerance")
    if key == "log":
        cmp = lambda e, a: f"({e} .eqv. {a})"
    elif real:
        cmp = lambda e, a: f"(abs({e} - {a}) <= tol)"
    else:
        cmp = lambda e, a: f"({e} == {a})"
    diff = (lambda e, a: f", difference=pf_format(abs({e} - {a}))") if numeric else (lambda e, a: "")
    if rank_a == 0:
        lines.append(f"        if (.not. {cmp('expected', 'actual')}) call pf_fail(file, line, "
                     f"'assertEqual', message, pf_format(expected), pf_format(actual){diff('expected', 'actual')})")
    else:
        if rank_e > 0:
            lines.append("        if (any(shape(expected) /= shape(actual))) then")
            lines.append("            call pf_fail(file, line, 'assertEqual: shapes differ', message)")
            lines.append("            return")
            lines.append("        end if")
        loops = ["i"] if rank_a == 1 else ["i", "j"]
        idx = "(" + ", ".join(loops) + ")"
        e = "expected" + (idx if rank_e > 0 else "")
        a = "actual" + idx
        if rank_a == 1:
            lines.append("        do i = 1, size(actual)")
            at = "        write(at, '(a,i0,a)') 'assertEqual: arrays differ at (', i, ')'"
        else:
            lines.append("        do j = 1, size(actual, 2)")
            lines.append("        do i = 1, size(actual, 1)")
            at = "        write(at, '(a,i0,a,i0,a)') 'assertEqual: arrays differ at (', i, ', ', j, ')'"
        lines.append(f"            if (.not. {cmp(e, a)}) then")
        lines.append("    " + at)
        lines.append(f"                call pf_fail(file, line, trim(at), message, pf_format({e}), "
                     f"pf_format({a}){diff(e, a)})")
        lines.append("                return")
        lines.append("            end if")
        lines.append("        end do")
        if rank_a == 2:
            lines.append("        end do")
    lines.append(f"    end subroutine {name}")
    return name, "\n".join(lines)


def compare_specific(op_name, op, key):
    decl, _, _ = TYPES[key]
    name = f"{op_name}_{key}"
    pretty = {"lt": "assertLessThan", "le": "assertLessThanOrEqual",
              "gt": "assertGreaterThan", "ge": "assertGreaterThanOrEqual"}[op_name]
    return name, f"""    subroutine {name}(a, b, message, file, line)
        {decl}, intent(in) :: a, b
        character(len=*), intent(in), optional :: message
        character(len=*), intent(in) :: file
        integer, intent(in) :: line
        if (.not. (a {op} b)) call pf_fail(file, line, '{pretty}: expected a {op} b', message, &
            'a = ' // pf_format(a), 'b = ' // pf_format(b), pf_format(a - b))
    end subroutine {name}"""


def relative_specific(key, rank_e, rank_a):
    decl, _, _ = TYPES[key]
    kind = "real64" if key == "r64" else "real32"
    name = f"relative_{key}_{rank_e}{rank_a}"
    e = "expected" + ("(i)" if rank_e else "")
    a = "actual" + ("(i)" if rank_a else "")
    body = [f"    subroutine {name}(expected, actual, tolerance, message, file, line)",
            f"        {decl}, intent(in) :: expected{dims(rank_e)}",
            f"        {decl}, intent(in) :: actual{dims(rank_a)}",
            f"        real({kind}), intent(in) :: tolerance",
            "        character(len=*), intent(in), optional :: message",
            "        character(len=*), intent(in) :: file",
            "        integer, intent(in) :: line"]
    if rank_a:
        body += ["        integer :: i", "        character(len=64) :: at",
                 "        do i = 1, size(actual)"]
        indent = "    "
    else:
        indent = ""
    body += [f"        {indent}if (.not. (abs({e} - {a}) <= tolerance * abs({e}))) then"]
    if rank_a:
        body += [f"        {indent}    write(at, '(a,i0,a)') 'assertRelativelyEqual: arrays differ at (', i, ')'"]
        what = "trim(at)"
    else:
        what = "'assertRelativelyEqual'"
    body += [f"        {indent}    call pf_fail(file, line, {what}, message, pf_format({e}), pf_format({a}), &",
             f"        {indent}        'relative ' // pf_format(abs({e} - {a}) / max(abs({e}), tiny({e}))))",
             f"        {indent}    return" if rank_a else "",
             f"        {indent}end if"]
    if rank_a:
        body += ["        end do"]
    body += [f"    end subroutine {name}"]
    return name, "\n".join(l for l in body if l != "")


def finite_specific(key, rank):
    decl, _, _ = TYPES[key]
    name = f"finite_{key}_{rank}"
    x = "x" + ("(i)" if rank else "")
    lines = [f"    subroutine {name}(x, message, file, line)",
             f"        {decl}, intent(in) :: x{dims(rank)}",
             "        character(len=*), intent(in), optional :: message",
             "        character(len=*), intent(in) :: file",
             "        integer, intent(in) :: line"]
    if rank:
        lines += ["        integer :: i", "        do i = 1, size(x)"]
    lines += [f"        if (.not. ieee_is_finite({x})) then",
              f"            call pf_fail(file, line, 'assertIsFinite', message, 'a finite value', pf_format({x}))",
              "            return",
              "        end if"]
    if rank:
        lines += ["        end do"]
    lines += [f"    end subroutine {name}"]
    return name, "\n".join(lines)


def support_asserts():
    generic = {"pf_assert_equal": [], "pf_assert_relatively_equal": [], "pf_assert_less_than": [],
               "pf_assert_less_than_or_equal": [], "pf_assert_greater_than": [],
               "pf_assert_greater_than_or_equal": [], "pf_assert_is_finite": []}
    bodies = []
    for key in TYPES:
        for rank_e, rank_a in ((0, 0), (0, 1), (1, 1), (0, 2), (2, 2)):
            if key == "chr" and rank_a > 0:
                continue
            name, body = equal_specific(key, rank_e, rank_a)
            generic["pf_assert_equal"].append(name)
            bodies.append(body)
    for key in ("int", "i8", "r64", "r32"):
        for op_name, op, gen in (("lt", "<", "pf_assert_less_than"), ("le", "<=", "pf_assert_less_than_or_equal"),
                                 ("gt", ">", "pf_assert_greater_than"),
                                 ("ge", ">=", "pf_assert_greater_than_or_equal")):
            name, body = compare_specific(op_name, op, key)
            generic[gen].append(name)
            bodies.append(body)
    for key in ("r64", "r32"):
        for rank_e, rank_a in ((0, 0), (0, 1), (1, 1)):
            name, body = relative_specific(key, rank_e, rank_a)
            generic["pf_assert_relatively_equal"].append(name)
            bodies.append(body)
        for rank in (0, 1):
            name, body = finite_specific(key, rank)
            generic["pf_assert_is_finite"].append(name)
            bodies.append(body)
    interfaces = []
    for gen, names in generic.items():
        interfaces.append(f"    interface {gen}")
        for i in range(0, len(names), 4):
            interfaces.append("        module procedure " + ", ".join(names[i:i + 4]))
        interfaces.append(f"    end interface {gen}")
    return f"""! generated by pfproc.py support: do not edit
!> Assertions of the pfunit_lite runner (pFUnit 4 meaning), one generic per assertion.
module pfunit_lite_asserts
    use, intrinsic :: iso_fortran_env, only: int64, real32, real64
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    use pfunit_lite_core, only: pf_fail, pf_format
    implicit none
    private
    public :: {", ".join(generic)}, pf_assert_true, pf_assert_false

{chr(10).join(interfaces)}

contains

    subroutine pf_assert_true(condition, message, file, line)
        logical, intent(in) :: condition
        character(len=*), intent(in), optional :: message
        character(len=*), intent(in) :: file
        integer, intent(in) :: line
        if (.not. condition) call pf_fail(file, line, 'assertTrue', message, '.true.', '.false.')
    end subroutine pf_assert_true

    subroutine pf_assert_false(condition, message, file, line)
        logical, intent(in) :: condition
        character(len=*), intent(in), optional :: message
        character(len=*), intent(in) :: file
        integer, intent(in) :: line
        if (condition) call pf_fail(file, line, 'assertFalse', message, '.false.', '.true.')
    end subroutine pf_assert_false

{chr(10).join(chr(10) + b for b in bodies)}
end module pfunit_lite_asserts
"""


def support_funit():
    return """! generated by pfproc.py support: do not edit
!> `use funit` in a serial .pf file: the assertions and the failure flag.
module funit
    use pfunit_lite_core, only: pf_failed
    use pfunit_lite_asserts
    implicit none
    public
end module funit
"""


def support_pfunit():
    return r"""! generated by pfproc.py support: do not edit
!> `use pfunit` in an MPI .pf file: the assertions, MpiTestMethod, and the MPI driver.
!> Each test runs once per listed process count on a fresh sub-communicator of that size;
!> ranks beyond it sit the run out. Failures print their rank; rank 0 keeps the count.
module pfunit
    use mpi_f08
    use pfunit_lite_core
    use pfunit_lite_asserts
    implicit none
    private
    public :: MpiTestMethod, pf_mpi_begin, pf_mpi_start, pf_mpi_finish, pf_mpi_end, pf_failed
    public :: pf_assert_equal, pf_assert_relatively_equal, pf_assert_less_than
    public :: pf_assert_less_than_or_equal, pf_assert_greater_than
    public :: pf_assert_greater_than_or_equal, pf_assert_true, pf_assert_false
    public :: pf_assert_is_finite

    !> The test's view of its communicator (an INTEGER handle, as in pFUnit 4).
    type :: MpiTestMethod
        integer :: comm = -1
        integer :: rank = -1
        integer :: npes = 0
        logical :: member = .false.
        type(MPI_Comm) :: sub
        character(len=128) :: name = ''
    contains
        procedure :: getMpiCommunicator
        procedure :: getProcessRank
        procedure :: getNumProcesses
    end type MpiTestMethod

    integer, save :: world_rank = 0, world_size = 1

contains

    integer function getMpiCommunicator(this)
        class(MpiTestMethod), intent(in) :: this
        getMpiCommunicator = this%comm
    end function getMpiCommunicator

    integer function getProcessRank(this)
        class(MpiTestMethod), intent(in) :: this
        getProcessRank = this%rank
    end function getProcessRank

    integer function getNumProcesses(this)
        class(MpiTestMethod), intent(in) :: this
        getNumProcesses = this%npes
    end function getNumProcesses

    subroutine pf_mpi_begin(name)
        character(len=*), intent(in) :: name
        integer :: ierr
        call MPI_Init(ierr)
        call MPI_Comm_rank(MPI_COMM_WORLD, world_rank, ierr)
        call MPI_Comm_size(MPI_COMM_WORLD, world_size, ierr)
        call pf_begin(name)
        call pf_set_rank(world_rank)
    end subroutine pf_mpi_begin

    !> Make the sub-communicator; true on the ranks that run this case.
    logical function pf_mpi_start(name, npes, this) result(run_here)
        character(len=*), intent(in) :: name
        integer, intent(in) :: npes
        type(MpiTestMethod), intent(inout) :: this
        integer :: colour, ierr
        character(len=32) :: suffix
        write(suffix, '(a,i0,a)') '[npes=', npes, ']'
        this%name = name // trim(suffix)
        this%npes = npes
        call pf_start(trim(this%name))
        if (npes > world_size) then
            if (world_rank == 0) call pf_fail(pf_file_name(), 0, 'needs ' // trim(suffix) // &
                ' processes but the run has fewer (raise MAX_PES)')
            this%member = .false.
            run_here = .false.
            return
        end if
        colour = merge(0, MPI_UNDEFINED, world_rank < npes)
        call MPI_Comm_split(MPI_COMM_WORLD, colour, world_rank, this%sub, ierr)
        this%member = world_rank < npes
        if (this%member) then
            this%comm = this%sub%mpi_val
            call MPI_Comm_rank(this%sub, this%rank, ierr)
        end if
        run_here = this%member
    end function pf_mpi_start

    !> Everyone agrees whether the case failed on any rank; rank 0 counts it.
    subroutine pf_mpi_finish(this)
        type(MpiTestMethod), intent(inout) :: this
        logical :: failed_here, failed_anywhere
        integer :: ierr, passed, failed
        character(len=8) :: verdict
        failed_here = pf_current_failed()
        call MPI_Allreduce(failed_here, failed_anywhere, 1, MPI_LOGICAL, MPI_LOR, MPI_COMM_WORLD, ierr)
        if (this%member) call MPI_Comm_free(this%sub, ierr)
        this%member = .false.
        if (world_rank == 0) then
            call pf_counts(passed, failed, merge(0, 1, failed_anywhere), merge(1, 0, failed_anywhere))
            verdict = merge('FAILED  ', 'passed  ', failed_anywhere)
            write(*, '(a)') verdict // trim(this%name)
            flush(6)
        end if
        call pf_reset_current()
    end subroutine pf_mpi_finish

    subroutine pf_mpi_end()
        integer :: ierr, passed, failed, status
        call pf_counts(passed, failed, 0, 0)
        call MPI_Bcast(failed, 1, MPI_INTEGER, 0, MPI_COMM_WORLD, ierr)
        if (world_rank == 0) then
            write(*, '(i0,a,i0,a)') passed, ' passed, ', failed, ' failed'
            flush(6)
        end if
        status = merge(1, 0, failed > 0)
        call MPI_Finalize(ierr)
        call pf_exit(status)
    end subroutine pf_mpi_end
end module pfunit
"""


def main(argv):
    try:
        if len(argv) == 4 and argv[0] == "test":
            text, module, tests, before, after, mpi = process(argv[1])
            with open(argv[2], "w", encoding="utf-8") as handle:
                # the header goes last so that line numbers match the .pf file
                handle.write(text)
                handle.write(f"\n! generated by pfproc.py from {os.path.basename(argv[1])}: do not edit\n")
            with open(argv[3], "w", encoding="utf-8") as handle:
                handle.write(driver_source(argv[1], module, tests, before, after, mpi))
            return 0
        if len(argv) == 2 and argv[0] == "support":
            os.makedirs(argv[1], exist_ok=True)
            for name, text in (("pfunit_lite_core.F90", support_core()),
                               ("pfunit_lite_asserts.F90", support_asserts()),
                               ("funit.F90", support_funit()),
                               ("pfunit.F90", support_pfunit())):
                path = os.path.join(argv[1], name)
                old = open(path, encoding="utf-8").read() if os.path.exists(path) else None
                if old != text:
                    with open(path, "w", encoding="utf-8") as handle:
                        handle.write(text)
            return 0
    except PfError as problem:
        print(f"pfproc: {problem}", file=sys.stderr)
        return 1
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
