#!/usr/bin/env python3
"""Check that an XDMF time series written by sphremesh opens: every DataItem's HDF5
reference resolves to a dataset of the stated dimensions and type, grid sizes match, and
times increase and equal each file's `time` attribute. With --paraview, also load it
through ParaView's Python (pvpython) when that is installed.

  scripts/sph_check_xdmf.py output/poiseuille/poiseuille.xdmf
  scripts/sph_check_xdmf.py output/poiseuille/poiseuille.xdmf --paraview

Exit status 0 when everything resolves, 1 with one line per problem (each naming the grid
and the reference) otherwise.
"""
import argparse
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

try:
    import h5py
    import numpy as np
except ImportError as missing:  # pragma: no cover - a message, not a traceback
    sys.exit(f"sph_check_xdmf: {missing.name} is missing; run scripts/install-deps "
             "and use .venv/bin/python")

MAX_REPORTED = 25
# XDMF NumberType/Precision -> numpy dtype kind and item size
NUMBER_TYPES = {"float": "f", "int": "i", "uint": "u", "char": "i", "uchar": "u"}


class XdmfProblem(Exception):
    """The file is not usable at all (unreadable XML, no time series)."""


class _Files:
    """HDF5 files opened once each (read-only), closed at the end."""

    def __init__(self):
        self.open = {}

    def get(self, h5_path):
        if h5_path not in self.open:
            try:
                self.open[h5_path] = h5py.File(h5_path, "r")
            except OSError as problem:
                self.open[h5_path] = problem
        return self.open[h5_path]

    def close(self):
        for f in self.open.values():
            if isinstance(f, h5py.File):
                f.close()


def _dims(item, where):
    text = item.get("Dimensions")
    if text is None:
        raise ValueError(f"{where}: DataItem without Dimensions")
    try:
        dims = tuple(int(d) for d in text.split())
    except ValueError:
        raise ValueError(f"{where}: Dimensions '{text}' are not whole numbers") from None
    if not dims:
        raise ValueError(f"{where}: empty Dimensions")
    return dims


def check(path):
    """Check an XDMF series. Returns (summary dict, list of problems as strings).

    Raises XdmfProblem when the file cannot be checked at all (missing, not XML, no
    temporal collection)."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isfile(path):
        raise XdmfProblem(f"{path}: no such file")
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as problem:
        raise XdmfProblem(f"{path}: not readable XML: {problem}") from None
    if root.tag != "Xdmf":
        raise XdmfProblem(f"{path}: root element is <{root.tag}>, not <Xdmf>")
    problems = []
    version = root.get("Version", "")
    if not version.startswith(("2", "3")):
        problems.append(f"<Xdmf Version='{version}'>: expected version 3 (or 2)")
    series = root.find("Domain/Grid")
    if series is None:
        raise XdmfProblem(f"{path}: no Domain/Grid element")
    if series.get("GridType") != "Collection" or series.get("CollectionType") != "Temporal":
        raise XdmfProblem(f"{path}: the first grid is not a temporal collection "
                          f"(GridType={series.get('GridType')!r}, "
                          f"CollectionType={series.get('CollectionType')!r})")
    grids = series.findall("Grid")
    if not grids:
        raise XdmfProblem(f"{path}: the time series is empty (no Grid in the collection)")

    files = _Files()
    summary = {"grids": len(grids), "items": 0, "times": [], "points": [], "files": set(),
               "attributes": set()}
    last_time = None
    try:
        for index, grid in enumerate(grids):
            name = f"grid {index} ({grid.get('Name', '?')})"
            time_el = grid.find("Time")
            time = None
            try:
                time = float(time_el.get("Value"))
            except (AttributeError, TypeError, ValueError):
                problems.append(f"{name}: no Time Value (or not a number)")
            if time is not None:
                name = f"{name} at t = {time:g}"
                if last_time is not None and not time > last_time:
                    problems.append(f"{name}: times do not increase ({last_time:g} then {time:g})")
                last_time = time
                summary["times"].append(time)
            topology = grid.find("Topology")
            count = None
            if topology is None:
                problems.append(f"{name}: no Topology")
            else:
                if topology.get("TopologyType", "").lower() != "polyvertex":
                    problems.append(f"{name}: TopologyType {topology.get('TopologyType')!r}, "
                                    "expected Polyvertex")
                try:
                    count = int(topology.get("NumberOfElements"))
                except (TypeError, ValueError):
                    problems.append(f"{name}: Topology without a valid NumberOfElements")
            summary["points"].append(count)
            items = []
            geometry = grid.find("Geometry")
            if geometry is None:
                problems.append(f"{name}: no Geometry")
            else:
                if geometry.get("GeometryType") != "XYZ":
                    problems.append(f"{name}: GeometryType {geometry.get('GeometryType')!r}, "
                                    "expected XYZ")
                found = geometry.findall("DataItem")
                if len(found) != 1:
                    problems.append(f"{name}: Geometry has {len(found)} DataItems, expected 1")
                items += [("geometry", "Vector3", item) for item in found]
            seen = set()
            for attribute in grid.findall("Attribute"):
                aname = attribute.get("Name")
                label = f"attribute {aname!r}"
                if not aname:
                    problems.append(f"{name}: Attribute without a Name")
                elif aname in seen:
                    problems.append(f"{name}: {label} appears twice")
                seen.add(aname)
                summary["attributes"].add(aname)
                if attribute.get("Center") != "Node":
                    problems.append(f"{name}: {label} has Center={attribute.get('Center')!r}, "
                                    "expected Node")
                found = attribute.findall("DataItem")
                if len(found) != 1:
                    problems.append(f"{name}: {label} has {len(found)} DataItems, expected 1")
                kind = attribute.get("AttributeType", "Scalar")
                items += [(label, kind, item) for item in found]
            for label, kind, item in items:
                problems += _check_item(name, label, kind, item, count, time, folder, files,
                                        summary)
    finally:
        files.close()
    return summary, problems


def _check_item(name, label, kind, item, count, time, folder, files, summary):
    problems = []
    reference = (item.text or "").strip()
    where = f"{name}: {label}: {reference or '(empty DataItem)'}"
    if item.get("Format", "XML").upper() != "HDF":
        return [f"{where}: Format {item.get('Format')!r}, expected HDF"]
    try:
        dims = _dims(item, where)
    except ValueError as problem:
        return [str(problem)]
    file_name, sep, dataset = reference.rpartition(":")
    if not sep or not file_name or not dataset:
        return [f"{where}: not a 'file.h5:/dataset' reference"]
    h5_path = file_name if os.path.isabs(file_name) else os.path.join(folder, file_name)
    f = files.get(h5_path)
    if isinstance(f, Exception):
        if not os.path.exists(h5_path):
            return [f"{where}: the file {h5_path} does not exist"]
        return [f"{where}: cannot open {h5_path}: {f}"]
    summary["files"].add(h5_path)
    if f.attrs.get("write_complete") != 1:
        problems.append(f"{where}: {file_name} has no write_complete marker (incomplete file)")
    if "time" not in f.attrs:
        problems.append(f"{where}: {file_name} has no 'time' attribute")
    elif time is not None:
        file_time = float(np.asarray(f.attrs["time"]).reshape(-1)[0])
        if abs(file_time - time) > 1e-12 * max(1.0, abs(time)):
            problems.append(f"{where}: Time Value {time!r} differs from the file's time "
                            f"{file_time!r}")
    if dataset not in f or not isinstance(f[dataset], h5py.Dataset):
        problems.append(f"{where}: no such dataset")
        return problems
    data = f[dataset]
    summary["items"] += 1
    if data.shape != dims:
        problems.append(f"{where}: Dimensions {' '.join(map(str, dims))} in the XDMF but shape "
                        f"{' x '.join(map(str, data.shape)) or 'scalar'} in the file")
    if count is not None and dims[0] != count:
        problems.append(f"{where}: {dims[0]} rows but the grid's NumberOfElements is {count}")
    if kind in ("Vector", "Vector3") and (len(dims) != 2 or dims[1] != 3):
        problems.append(f"{where}: a {kind.replace('3', '')} needs Dimensions 'N 3', got "
                        f"'{' '.join(map(str, dims))}'")
    if kind == "Scalar" and len(dims) != 1:
        problems.append(f"{where}: a Scalar needs Dimensions 'N', got '{' '.join(map(str, dims))}'")
    number = item.get("NumberType", item.get("DataType", "Float")).lower()
    precision = item.get("Precision", "4")
    expected_kind = NUMBER_TYPES.get(number)
    if expected_kind is None:
        problems.append(f"{where}: unknown NumberType {number!r}")
    elif data.dtype.kind != expected_kind or str(data.dtype.itemsize) != precision:
        problems.append(f"{where}: NumberType {item.get('NumberType')} Precision {precision} "
                        f"but the dataset is {data.dtype}")
    return problems


def load_with_paraview(path, summary, timeout=300):
    """Load the series through pvpython; returns (ok, message)."""
    pvpython = shutil.which("pvpython")
    if pvpython is None:
        return True, "pvpython not found on PATH: ParaView check skipped"
    script = ("from paraview import simple\n"
              f"r = simple.XDMFReader(FileNames=[{os.path.abspath(path)!r}])\n"
              "steps = list(r.TimestepValues) if r.TimestepValues else []\n"
              "r.UpdatePipeline(steps[-1] if steps else 0.0)\n"
              "print('SPH', r.GetDataInformation().GetNumberOfPoints(), len(steps))\n")
    try:
        result = subprocess.run([pvpython, "--force-offscreen-rendering", "-c", script],
                                capture_output=True, text=True, timeout=timeout)
        if result.returncode != 0 and "force-offscreen" in result.stderr:
            result = subprocess.run([pvpython, "-c", script], capture_output=True, text=True,
                                    timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"{path}: ParaView did not load it within {timeout} s"
    line = [l for l in result.stdout.splitlines() if l.startswith("SPH ")]
    if result.returncode != 0 or not line:
        return False, f"{path}: ParaView could not load it: {result.stderr.strip()[-2000:]}"
    points, steps = (int(v) for v in line[-1].split()[1:3])
    expected_steps = summary["grids"]
    expected_points = summary["points"][-1]
    if steps != expected_steps or (expected_points is not None and points != expected_points):
        return False, (f"{path}: ParaView sees {points} points and {steps} time steps; the XDMF "
                       f"says {expected_points} points (last step) and {expected_steps} steps")
    return True, f"ParaView (pvpython, XDMFReader) loaded it: {points} points, {steps} time steps"


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Exit status: 0 all good, 1 problems found (one line each on stderr).")
    parser.add_argument("xdmf", metavar="FILE.xdmf", help="the <case>.xdmf file of a run")
    parser.add_argument("--paraview", action="store_true",
                        help="also load the series with ParaView's pvpython, if on PATH")
    parser.add_argument("--quiet", "-q", action="store_true", help="print only problems")
    args = parser.parse_args(argv)
    try:
        summary, problems = check(args.xdmf)
    except XdmfProblem as problem:
        print(f"sph_check_xdmf: {problem}", file=sys.stderr)
        return 1
    if problems:
        for problem in problems[:MAX_REPORTED]:
            print(f"sph_check_xdmf: {args.xdmf}: {problem}", file=sys.stderr)
        if len(problems) > MAX_REPORTED:
            print(f"sph_check_xdmf: ... and {len(problems) - MAX_REPORTED} more problems",
                  file=sys.stderr)
        print(f"sph_check_xdmf: {args.xdmf}: {len(problems)} problem(s) found", file=sys.stderr)
        return 1
    if not args.quiet:
        times = summary["times"]
        points = [p for p in summary["points"] if p is not None]
        print(f"{args.xdmf}: OK: {summary['grids']} time steps (t = {times[0]:g} .. "
              f"{times[-1]:g} s), {min(points)}..{max(points)} points, "
              f"{len(summary['attributes'])} attributes, {summary['items']} data items in "
              f"{len(summary['files'])} HDF5 files resolved")
    if args.paraview:
        ok, message = load_with_paraview(args.xdmf, summary)
        print(message if ok else f"sph_check_xdmf: {message}", file=sys.stdout if ok else sys.stderr)
        if not ok:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
