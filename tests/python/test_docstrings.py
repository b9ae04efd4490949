"""Every public procedure of src/ carries a `!>` comment right above it (issue 14: the API
documentation that scripts/api-docs builds with FORD comes from these comments).

    .venv/bin/python -m unittest discover -s tests/python -v
"""
import glob
import os
import re
import unittest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

PUBLIC = re.compile(r"^\s*public\s*::\s*((?:[^\n&!]|&[ \t]*\n)+)", re.MULTILINE | re.IGNORECASE)
PROCEDURE = re.compile(
    r"\s*(?:(?:pure|elemental|recursive|impure|module)\s+)*"
    r"(?:(?:integer|real|logical|character|type|class)\s*(?:\([^)]*\))?\s+)?"
    r"(subroutine|function)\s+(\w+)", re.IGNORECASE)


def undocumented(path):
    """Public procedures of one source file with no `!>` line right above them."""
    with open(path) as f:
        text = f.read()
    public = set()
    for match in PUBLIC.finditer(text):
        public.update(n.lower() for n in re.split(r"[,&\s]+", match.group(1)) if n)
    lines = text.split("\n")
    missing = []
    for i, line in enumerate(lines):
        match = PROCEDURE.match(line)
        if not match or line.strip().lower().startswith("end"):
            continue
        if match.group(2).lower() not in public:
            continue
        j = i - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        if j < 0 or not lines[j].strip().startswith("!>"):
            missing.append(f"{os.path.relpath(path, ROOT)}:{i + 1}: {match.group(2)}")
    return missing


class TestDocstrings(unittest.TestCase):

    def test_every_public_procedure_is_documented(self):
        missing = []
        for path in sorted(glob.glob(os.path.join(ROOT, "src", "**", "*.f90"), recursive=True)):
            missing += undocumented(path)
        self.assertEqual([], missing, "public procedures without a `!>` comment above them")

    def test_the_check_sees_a_missing_comment(self):
        source = ("module m\n    public :: documented, bare\ncontains\n"
                  "    !> Says what it does.\n    subroutine documented()\n"
                  "    end subroutine documented\n\n"
                  "    pure integer function bare(x)\n        integer, intent(in) :: x\n"
                  "        bare = x\n    end function bare\nend module m\n")
        import tempfile
        with tempfile.NamedTemporaryFile("w", suffix=".f90", delete=False) as f:
            f.write(source)
        try:
            found = undocumented(f.name)
        finally:
            os.remove(f.name)
        self.assertEqual(1, len(found))
        self.assertTrue(found[0].endswith(": bare"))


if __name__ == "__main__":
    unittest.main()
