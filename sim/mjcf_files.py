"""Every file an MJCF model reads: the model itself, its ``<include>`` files and its asset files.

MuJoCo's rules, which this module follows:

- ``<include file=...>`` names a file relative to the including file's folder, else to the main
  model's folder (MuJoCo 3/4 try both); includes nest.
- mesh, height field and skin files are found under ``compiler meshdir``, textures (``file`` and the
  six cube faces) under ``compiler texturedir`` (``assetdir`` sets both); those folders are relative
  to the main model's folder; ``strippath`` keeps only a file's base name.

A robot is recorded by these files (see :mod:`demo.sim.robot_record`), so they must be referenced by
relative paths: an absolute reference would point outside any copy of the robot, and is refused.
Includes are found by reading the XML (no MuJoCo), so that with ``within`` set an include leaving
that folder is refused before MuJoCo opens it; asset names come from MuJoCo's own parse.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco

from demo.errors import DemoError


def _inside(path: Path, within: Path | None) -> bool:
    return within is None or Path(os.path.normpath(path)).is_relative_to(Path(os.path.normpath(within)))


def _reference(name: str, bases: list[Path], mjcf: Path, within: Path | None) -> Path:
    """The file ``name`` refers to: the first of ``bases / name`` that exists (else the first)."""
    if Path(name).is_absolute():
        raise DemoError(mjcf, f"refers to {name} by an absolute path; reference robot files relative to the MJCF "
                              "so that a store can carry them")
    candidates = [Path(os.path.normpath(base / name)) for base in bases]
    for candidate in candidates:
        if not _inside(candidate, within):
            raise DemoError(mjcf, f"refers to {name}, which lies outside {within}; refusing to read it")
    return next((c for c in candidates if c.is_file()), candidates[0])


def _xml_files(mjcf: Path, within: Path | None) -> list[Path]:
    """The model file and every file it includes, depth first."""
    main_dir = mjcf.parent
    found: list[Path] = []
    todo = [mjcf]
    while todo:
        path = todo.pop()
        if path in found:
            continue
        found.append(path)
        try:
            tree = ET.parse(path)
        except (OSError, ET.ParseError) as exc:
            raise DemoError(path, f"cannot read MJCF ({exc})") from None
        for element in tree.iter("include"):
            name = element.get("file")
            if name:
                todo.append(_reference(name, [path.parent, main_dir], path, within))
    return found


def _asset_names(spec: mujoco.MjSpec) -> tuple[list[str], list[str]]:
    """(files under meshdir, files under texturedir), as written in the model."""
    mesh_like = [a.file for group in (spec.meshes, spec.hfields, spec.skins) for a in group]
    textures = [t.file for t in spec.textures] + [f for t in spec.textures for f in t.cubefiles]
    keep = (lambda name: os.path.basename(name)) if spec.strippath else (lambda name: name)
    return [keep(n) for n in mesh_like if n], [keep(n) for n in textures if n]


def mjcf_files(mjcf: str | Path, within: str | Path | None = None) -> list[Path]:
    """Absolute, normalised paths of the files the model at ``mjcf`` reads (the model first).

    ``within``: refuse any reference that leaves this folder (for a robot copied into a store).
    Raises DemoError naming the model for an absolute or escaping reference or an unreadable file.
    """
    mjcf = Path(os.path.normpath(Path(mjcf).absolute()))
    within = Path(within).absolute() if within is not None else None
    if not _inside(mjcf, within):
        raise DemoError(mjcf, f"lies outside {within}; refusing to read it")
    files = _xml_files(mjcf, within)
    try:
        spec = mujoco.MjSpec.from_file(str(mjcf))
    except Exception as exc:  # mujoco raises ValueError with the parser's message
        raise DemoError(mjcf, f"cannot load MJCF: {str(exc).strip().splitlines()[0][:200]}") from None
    meshes, textures = _asset_names(spec)
    for folder, names in ((spec.meshdir, meshes), (spec.texturedir, textures)):
        if folder and Path(folder).is_absolute():
            raise DemoError(mjcf, f"sets an absolute asset folder {folder}; make it relative to the MJCF so that "
                                  "a store can carry the robot's files")
        base = mjcf.parent / folder if folder else mjcf.parent
        files.extend(_reference(name, [base], mjcf, within) for name in names)
    return list(dict.fromkeys(files))
