#!/usr/bin/env python3
"""Check that an XDMF time series written by sphremesh opens: every DataItem's HDF5
reference resolves to a dataset of the stated dimensions, grid sizes match, and times
increase and equal each file's `time` attribute. With --paraview, also load it through
ParaView's Python (pvpython) when that is installed.

  scripts/sph_check_xdmf.py output/poiseuille/poiseuille.xdmf
"""
import argparse
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

try:
    import h5py
except ImportError:  # pragma: no cover
    sys.exit("sph_check_xdmf: h5py is missing; run scripts/install-deps and use .venv/bin/python")


class XdmfProblem(Exception):
    pass


def check(path):
    folder = os.path.dirname(os.path.abspath(path))
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as problem:
        raise XdmfProblem(f"{path}: not readable XML: {problem}") from None
    series = root.find("Domain/Grid")
    if series is None or series.get("CollectionType") != "Temporal":
        raise XdmfProblem(f"{path}: no temporal collection grid")
    grids = series.findall("Grid")
    if not grids:
        raise XdmfProblem(f"{path}: the time series is empty")
    last_time = None
    checked = 0
    for grid in grids:
        time = float(grid.find("Time").get("Value"))
        if last_time is not None and time <= last_time:
            raise XdmfProblem(f"{path}: times do not increase ({last_time} then {time})")
        last_time = time
        count = int(grid.find("Topology").get("NumberOfElements"))
        if grid.find("Topology").get("TopologyType") != "Polyvertex":
            raise XdmfProblem(f"{path}: grid at t = {time} is not Polyvertex")
        for item in grid.iter("DataItem"):
            reference = item.text.strip()
            file_name, _, dataset = reference.partition(":")
            h5_path = os.path.join(folder, file_name)
            dims = tuple(int(d) for d in item.get("Dimensions").split())
            try:
                with h5py.File(h5_path, "r") as f:
                    if dataset not in f:
                        raise XdmfProblem(f"{path}: {reference}: no such dataset")
                    shape = f[dataset].shape
                    file_time = float(f.attrs["time"])
            except OSError as problem:
                raise XdmfProblem(f"{path}: {reference}: cannot open {h5_path}: {problem}") from None
            if shape != dims:
                raise XdmfProblem(f"{path}: {reference}: dimensions {dims} in the XDMF, {shape} in the file")
            if dims[0] != count:
                raise XdmfProblem(f"{path}: {reference}: {dims[0]} rows but NumberOfElements = {count}")
            if abs(file_time - time) > 1e-12 * max(1.0, abs(time)):
                raise XdmfProblem(f"{path}: {reference}: file time {file_time} differs from {time}")
            checked += 1
    return len(grids), checked


def load_with_paraview(path):
    pvpython = shutil.which("pvpython")
    if pvpython is None:
        return "pvpython not installed: ParaView load skipped"
    script = ("from paraview import simple\n"
              f"r = simple.XDMFReader(FileNames=[{os.path.abspath(path)!r}])\n"
              "r.UpdatePipeline(r.TimestepValues[-1] if r.TimestepValues else 0)\n"
              "print(r.GetDataInformation().GetNumberOfPoints(), len(r.TimestepValues))\n")
    result = subprocess.run([pvpython, "-c", script], capture_output=True, text=True, timeout=300)
    if result.returncode != 0:
        raise XdmfProblem(f"{path}: ParaView could not load it: {result.stderr.strip()}")
    return f"ParaView loaded it: points, time steps = {result.stdout.strip()}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("xdmf", help="the <case>.xdmf file")
    parser.add_argument("--paraview", action="store_true", help="also load it with pvpython if installed")
    args = parser.parse_args(argv)
    try:
        grids, items = check(args.xdmf)
        print(f"{args.xdmf}: {grids} time steps, {items} data items resolved")
        if args.paraview:
            print(load_with_paraview(args.xdmf))
    except XdmfProblem as problem:
        print(f"sph_check_xdmf: {problem}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
