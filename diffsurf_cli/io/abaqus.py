"""A small reader of Abaqus/CalculiX decks (.inp), for the decks meshio's reader cannot read
or misreads: ``*NODE``, ``*ELEMENT``, ``*NSET``, ``*ELSET`` and ``*SURFACE``, following
``*INCLUDE`` (and ``INPUT=`` on those keywords). Every other keyword is skipped with its data
lines.

What meshio's reader (5.3) does not do and this one does: shell and membrane elements other
than S3/S4/S4R/S8R (S6, S8, M3D*, US3: surface cells), plane elements other than CPS3/CPS4/
CPE6 (CPS*/CPE*/CAX*), element types it does not know at all (springs, masses, network and
coupling elements: read past and left out), keyword parameters in lower case (``type=s8``),
``*NODE`` data lines ending with a comma or with blank fields, several ``*NODE`` blocks,
comment lines inside data, ``GENERATE`` with two values, set names inside sets, ``NSET=`` on
``*NODE``, sets defined again (their members are added, as in Abaqus), files included from the
including file's folder with their sets and surfaces.

Element node orderings: Abaqus's (and CalculiX's) are meshio's for every type read here: the
corners, then the mid-side nodes in the order of the sides (c1 c2, c2 c3, ...): S6/STRI65 as
meshio's triangle6, S8/S8R as quad8 (CalculiX's manual, figures C2D6 and C2D8; the volume
types as in `abaqus_surface`).

Names are kept as written; names that differ only by case are told apart here and matched by
`mesh._resolve_zone` as for a deck meshio read. Every failure is a ReadError of one line naming
the deck, the file and line where it is, and what was expected.
"""
from __future__ import annotations

import functools
import logging
import os
import re
from dataclasses import dataclass, field

import numpy as np

from .errors import ReadError

__all__ = ["CELL_TYPES", "Deck", "Surface", "deck_mesh", "meshio_misreads", "read_deck",
           "read_past"]

_log = logging.getLogger("diffsurf")

#: Abaqus element type -> meshio cell type, for the elements whose cells a target is made of
#: or may be made of (surface and volume cells); lines (trusses, beams) are read to be counted.
#: meshio's own table (5.3) is a subset, but for C3D4H, which it maps to no meshio type.
CELL_TYPES = {
    # shells and membranes: surface cells
    **{t: "triangle" for t in ("S3", "S3R", "S3RS", "STRI3", "M3D3", "US3", "R3D3")},
    **{t: "quad" for t in ("S4", "S4R", "S4RS", "S4RSW", "S4R5", "M3D4", "M3D4R", "R3D4")},
    **{t: "triangle6" for t in ("S6", "STRI65", "M3D6")},
    **{t: "quad8" for t in ("S8", "S8R", "S8R5", "M3D8", "M3D8R")},
    **{t: "quad9" for t in ("S9R5", "M3D9", "M3D9R")},
    # plane stress, plane strain, axisymmetric: surface cells in their plane (as meshio reads
    # CPS3, CPS4, CPE6)
    **{p + s: k for p in ("CPS", "CPE", "CAX") for s, k in (
        ("3", "triangle"), ("4", "quad"), ("4R", "quad"), ("4I", "quad"), ("4P", "quad"),
        ("6", "triangle6"), ("6M", "triangle6"), ("8", "quad8"), ("8R", "quad8"))},
    # volumes: their boundary
    **{t: "tetra" for t in ("C3D4", "C3D4H", "C3D4T")},
    **{t: "tetra10" for t in ("C3D10", "C3D10H", "C3D10I", "C3D10M", "C3D10MH", "C3D10T")},
    **{t: "wedge" for t in ("C3D6", "C3D6H", "C3D6T")},
    **{t: "wedge15" for t in ("C3D15", "C3D15H")},
    **{t: "hexahedron" for t in ("C3D8", "C3D8H", "C3D8I", "C3D8IH", "C3D8R", "C3D8RH",
                                 "C3D8T")},
    **{t: "hexahedron20" for t in ("C3D20", "C3D20H", "C3D20R", "C3D20RH", "C3D20T")},
    # trusses and beams: lines (left out of a target, counted)
    **{t: "line" for t in ("T2D2", "T2D2H", "T3D2", "T3D2H", "B21", "B21H", "B31", "B31H",
                           "B31R")},
    **{t: "line3" for t in ("T2D3", "T2D3H", "T3D3", "T3D3H", "B22", "B22H", "B32", "B32H",
                            "B32R", "B33", "B33H")},
}

#: element types with a *SURFACE face on each side of the element (the cell itself, SPOS or
#: S2, and the cell reversed, SNEG or S1: CalculiX's surfaces.f), and no face that is a
#: surface cell otherwise (S3... are edges)
SHELL_TYPES = frozenset(t for t, k in CELL_TYPES.items()
                        if k in ("triangle", "quad", "triangle6", "quad8", "quad9")
                        and not t.startswith(("CPS", "CPE", "CAX")))

#: nodes per element of the types read past (CalculiX's other elements, fluid volumes)
_OTHER_NODES = {"D": 3, "DCOUP3D": 1, "MASS": 1, "SPRING1": 1, "SPRING2": 2, "SPRINGA": 2,
                "DASHPOTA": 2, "GAPUNI": 2, "U1": 2, "F3D4": 4, "F3D6": 6, "F3D8": 8,
                "F3D8R": 8, "F3D20": 20, "F3D20R": 20}

_NODES = {"line": 2, "line3": 3, "triangle": 3, "quad": 4, "triangle6": 6, "quad8": 8,
          "quad9": 9, "tetra": 4, "tetra10": 10, "wedge": 6, "wedge15": 15, "hexahedron": 8,
          "hexahedron20": 20}

#: node and element numbers are positive and below this (Abaqus: 2^31 - 1)
_NUMBER_MAX = 2**31 - 1
#: numbers of a data line beyond this (any invalid as node or element numbers) are this
_CLAMP = 2**62
#: *INCLUDE depth beyond which a deck is taken to include itself
_INCLUDE_DEPTH = 32
#: keywords whose data this reader reads; the data of any other is skipped
_READ = ("NODE", "ELEMENT", "NSET", "ELSET", "SURFACE", "INCLUDE")


@dataclass
class Surface:
    """One ``*SURFACE`` of a deck: its name, TYPE (ELEMENT or NODE) and data lines as
    (element or node number or set name, face id string or "", where: "line 12" or
    "sub.inp line 3")."""

    name: str
    type: str
    lines: list = field(default_factory=list)


@dataclass
class Block:
    """One ``*ELEMENT`` block: its Abaqus type, meshio cell type (None: an element read past),
    element numbers (c,), connectivity (c, k) as point indices (empty for elements read
    past) and where its keyword line is."""

    etype: str
    kind: str | None
    numbers: np.ndarray
    conn: np.ndarray
    where: str
    count: int = -1  # elements, where ``numbers`` does not hold them (a type of unknown size)

    def __len__(self) -> int:
        return self.count if self.count >= 0 else len(self.numbers)


@dataclass
class Deck:
    """A deck as this reader reads it: its points in file order (includes in place), its
    element blocks, sets and surfaces; ``files``: the deck and every included file, with
    their (mtime, size) when read."""

    path: str
    numbers: np.ndarray  # (n,) node number of each point
    points: np.ndarray  # (n, 3) float64
    blocks: list
    nsets: dict  # name -> parts: ("n", [numbers]) | ("range", (a, b, step)) | ("set", name)
    elsets: dict  # the same, for elements; ("block", index) for ELSET= on *ELEMENT
    elset_order: list  # names, in meshio's order (*ELSET first, then ELSET= of *ELEMENT)
    surfaces: dict
    files: list
    wheres: dict = field(default_factory=dict)  # (kind, set name) -> where first defined
    skipped: dict = field(default_factory=dict)  # set name -> references to nothing

    def node_index(self, numbers: np.ndarray) -> np.ndarray:
        """Point index of each node number (-1: not defined); a number defined twice is its
        last definition, as in Abaqus."""
        return _lookup(self.numbers, np.arange(len(self.numbers)), numbers)

    def element_index(self, numbers: np.ndarray):
        """(block, row) of each element number (-1, -1 where none)."""
        numbers = np.asarray(numbers, dtype=np.int64).reshape(-1)
        if sum(len(b.numbers) for b in self.blocks) == 0:
            return np.full(len(numbers), -1), np.full(len(numbers), -1)
        block = np.concatenate([np.full(len(b.numbers), i) for i, b in enumerate(self.blocks)])
        row = np.concatenate([np.arange(len(b.numbers)) for b in self.blocks])
        at = _lookup(np.concatenate([b.numbers for b in self.blocks]), np.arange(len(block)),
                     numbers)
        found = at >= 0
        at = np.where(found, at, 0)
        return np.where(found, block[at], -1), np.where(found, row[at], -1)

    def node_set(self, name: str, _seen=()) -> np.ndarray:
        """Sorted point indices of node set ``name`` (exact name)."""
        return self._members("NSET", name, _seen)

    def element_set(self, name: str, _seen=()) -> np.ndarray:
        """Sorted unique element numbers of element set ``name`` (exact name)."""
        return self._members("ELSET", name, _seen)

    @functools.cached_property
    def _all_elements(self) -> np.ndarray:
        nums = [b.numbers for b in self.blocks]
        return np.unique(np.concatenate(nums)) if nums else np.zeros(0, np.int64)

    def _members(self, kind: str, name: str, seen) -> np.ndarray:
        memo = self.__dict__.setdefault("_memo", {})
        if (kind, name) not in memo:
            memo[kind, name] = self._resolve(kind, name, seen)
        return memo[kind, name]

    def _resolve(self, kind: str, name: str, seen) -> np.ndarray:
        sets = self.nsets if kind == "NSET" else self.elsets
        numbers, picked, lost = [], [], 0
        for part, value in sets[name]:
            if part == "set":
                key = _find(sets, value)
                if key is None:
                    where = self.wheres.get((kind, name), "")
                    what = "node" if kind == "NSET" else "element"
                    raise ReadError(f"{self.path}: {where}: *{kind} {name!r} names {value!r}, "
                                    f"which is no {what} set of the deck")
                if key not in seen and key != name:  # a set inside itself: left out
                    picked.append(self._members(kind, key, seen + (name,)))
            elif part == "block":
                picked.append(self.blocks[value].numbers if kind == "ELSET" else None)
            elif part == "range":
                start, stop, step = value
                pool = self.numbers if kind == "NSET" else self._all_elements
                hit = pool[(pool >= start) & (pool <= stop) & ((pool - start) % step == 0)]
                picked.append(np.unique(hit) if kind == "ELSET" else self.node_index(hit))
            else:
                numbers.extend(value)
        if numbers:
            numbers = np.array(numbers, dtype=np.int64)
            if kind == "NSET":
                index = self.node_index(numbers)
                lost += int(np.sum(index < 0))
                picked.append(index[index >= 0])
            else:
                known = np.isin(numbers, self._all_elements)
                lost += int(np.sum(~known))
                picked.append(numbers[known])
        if lost:
            self.skipped[(kind, name)] = lost
        picked = [p for p in picked if p is not None and len(p)]
        return np.unique(np.concatenate(picked)) if picked else np.zeros(0, np.int64)


def _lookup(keys: np.ndarray, values: np.ndarray, query: np.ndarray) -> np.ndarray:
    """values[i] where keys[i] == q, for each q of ``query`` (the last such i); -1 where none."""
    query = np.asarray(query, dtype=np.int64).reshape(-1)
    if len(keys) == 0:
        return np.full(len(query), -1, np.int64)
    # the last of equal keys: a stable sort of the reversed keys puts it first
    rev = keys[::-1]
    order = np.argsort(rev, kind="stable")
    sorted_keys = rev[order]
    pos = np.searchsorted(sorted_keys, query)
    pos = np.minimum(pos, len(keys) - 1)
    found = sorted_keys[pos] == query
    return np.where(found, values[::-1][order][pos], -1).astype(np.int64)


def _find(names, name: str):
    """The name of ``names`` that ``name`` is: the same, else the one differing by case."""
    if name in names:
        return name
    same = [n for n in names if n.casefold() == name.casefold()]
    return same[0] if len(same) == 1 else None


# --------------------------------------------------------------------------------------------
# the text
# --------------------------------------------------------------------------------------------


def _text(path: str, top: str, where: str) -> str:
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise ReadError(f"{top}: {where}no such file {path!r}") from None
    except IsADirectoryError:
        raise ReadError(f"{top}: {where}{path!r} is a directory, expected a file") from None
    except OSError as exc:
        raise ReadError(f"{top}: {where}cannot read {path!r} "
                        f"({exc.strerror or type(exc).__name__})") from None
    return data.decode("utf-8", errors="replace")


def _params(line: str) -> dict:
    """The parameters of a keyword line: upper-case key -> value as written ("" if none)."""
    out = {}
    for word in line.split(",")[1:]:
        key, _, value = word.partition("=")
        key = " ".join(key.split()).upper()
        if key:
            out[key] = value.strip().strip('"').strip()
    return out


def _keyword(line: str) -> str:
    return " ".join(line[1:].partition(",")[0].split()).upper()


_FORTRAN = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)[dD][+-]?\d+")


def _float(text: str) -> float:
    """A coordinate: a number as Fortran reads it (1.5, 1.5e3, 1.5d3, 1.5D+3); blank is 0.
    (nan and inf are read: the finiteness check of the target's nodes names them.)"""
    try:
        return float(text)
    except ValueError:
        text = text.strip()
        if not text:
            return 0.0
        if _FORTRAN.fullmatch(text):
            return float(text.replace("d", "e").replace("D", "e"))
        raise


def _int(text: str) -> int:
    return int(text)  # ValueError for anything but an integer (spaces around it allowed)


def _clamped(ints: list) -> list:
    """``ints`` within ±_CLAMP (numbers beyond are no valid node or element number all the
    same, and fit in int64)."""
    if ints and (max(ints) > _CLAMP or min(ints) < -_CLAMP):
        return [max(-_CLAMP, min(v, _CLAMP)) for v in ints]
    return ints


def _where(at) -> str:
    """Where a line is, from `_Lines.at`: "line 12", or "sub.inp line 3" in an included
    file."""
    if isinstance(at, str):
        return at
    shown, number = at
    return f"line {number}" if shown is None else f"{shown} line {number}"


class _Lines:
    """The data and keyword lines of a deck and the files it includes, in reading order:
    (text stripped, where). Blank and comment (``**``) lines are left out."""

    def __init__(self, path: str):
        self.top = path
        self.stack = []  # (lines, index, shown name, folder, real path)
        self.files = []
        self._push(path, None, "")

    def _push(self, path: str, shown: str, where: str):
        if "\x00" in path:
            raise ReadError(f"{self.top}: {where}{path!r} is no file name (a NUL character)")
        real = os.path.realpath(path)
        if len(self.stack) >= _INCLUDE_DEPTH or any(s[4] == real for s in self.stack):
            raise ReadError(f"{self.top}: {where}{shown or path!r} includes itself")
        text = _text(path, self.top, where)
        try:
            stat = os.stat(path)
            self.files.append((path, stat.st_mtime_ns, stat.st_size))
        except OSError:  # read a moment ago: gone since
            self.files.append((path, 0, -1))
        self.stack.append([text.splitlines(), 0, shown, os.path.dirname(path), real])

    def include(self, name: str, where: str):
        """Read ``name`` (relative to the folder of the file being read) next."""
        if not name:
            raise ReadError(f"{self.top}: {where}: *INCLUDE without INPUT=, expected "
                            f"*INCLUDE, INPUT=file")
        folder = self.stack[-1][3]
        path = name if os.path.isabs(name) else os.path.join(folder, name)
        shown = os.path.relpath(path, os.path.dirname(self.top) or ".") if not \
            os.path.isabs(name) else name
        self._push(path, shown, f"{where}: *INCLUDE, INPUT={name}: ")

    def at(self, number: int) -> tuple:
        """Line ``number`` of the file being read, for `_where`."""
        return self.stack[-1][2], number

    def __iter__(self):
        while self.stack:
            top = self.stack[-1]
            lines, i = top[0], top[1]
            if i >= len(lines):
                self.stack.pop()
                continue
            top[1] = i + 1
            line = lines[i].strip()
            if not line or line.startswith("**"):
                continue
            yield line, i + 1


# --------------------------------------------------------------------------------------------
# the deck
# --------------------------------------------------------------------------------------------


def read_deck(path: str) -> Deck:
    """The deck ``path`` and every file it includes, read once per version of those files."""
    try:
        stat = os.stat(path)
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({exc.strerror or exc})") from None
    deck = _parse(path, stat.st_mtime_ns, stat.st_size)
    for name, mtime, size in deck.files[1:]:  # an included file changed since: read again
        try:
            st = os.stat(name)
        except OSError:
            st = None
        if st is None or (st.st_mtime_ns, st.st_size) != (mtime, size):
            _parse.cache_clear()
            return _parse(path, stat.st_mtime_ns, stat.st_size)
    return deck


class _Reader:
    """The state of one pass over a deck."""

    def __init__(self, path: str):
        self.path = path
        self.node_numbers, self.coords = [], []
        self.blocks = []  # (etype, kind, size, rows [(ints, where)], where)
        self.nsets, self.elsets = {}, {}
        self.elset_order, self.element_sets = [], []
        self.surfaces = {}
        self.wheres = {}

    def fail(self, at, what: str):
        raise ReadError(f"{self.path}: {_where(at)}: {what}")

    def add_set(self, sets: dict, kind: str, name: str, at) -> list:
        if not name:
            self.fail(at, f"*{kind} without {kind}=, expected *{kind}, {kind}=NAME")
        self.wheres.setdefault((kind, name), _where(at))
        return sets.setdefault(name, [])

    def node(self, line: str, where: str, nset):
        fields = line.split(",")
        try:
            number = _int(fields[0])
            xyz = [_float(f) for f in fields[1:4]]
        except ValueError:
            self.fail(where, f"cannot read {line[:60]!r} in *NODE, expected a node number and "
                             f"its coordinates")
        if not 0 < number <= _NUMBER_MAX:
            self.fail(where, f"node number {number} in *NODE, expected 1 to {_NUMBER_MAX}")
        self.node_numbers.append(number)
        self.coords.append(xyz + [0.0] * (3 - len(xyz)))
        if nset is not None:
            nset.append(("n", [number]))

    def set_line(self, line: str, where: str, kind: str, members: list, generate: bool):
        fields = [f.strip() for f in line.split(",")]
        fields = [f for f in fields if f]
        if generate:
            try:
                start, stop, *step = (max(-_CLAMP, min(_int(f), _CLAMP)) for f in fields)
            except ValueError:
                self.fail(where, f"cannot read {line[:60]!r} in *{kind}, GENERATE, expected "
                                 f"first, last[, increment]")
            step = step[0] if step else 1
            if len(fields) > 3 or step <= 0 or stop < start:
                self.fail(where, f"{line[:60]!r} in *{kind}, GENERATE, expected first, "
                                 f"last >= first[, increment > 0]")
            members.append(("range", (start, stop, step)))
            return
        try:
            members.append(("n", _clamped(list(map(int, fields)))))
        except ValueError:
            for f in fields:
                try:
                    members.append(("n", _clamped([int(f)])))
                except ValueError:
                    members.append(("set", f.strip('"')))

    def element_block(self, params: dict, where: str):
        etype = params.get("TYPE", "").upper()
        if not etype:
            self.fail(where, "*ELEMENT without TYPE=, expected *ELEMENT, TYPE=...")
        kind = CELL_TYPES.get(etype)
        size = _NODES[kind] if kind else _OTHER_NODES.get(etype)
        block = (etype, kind, size, [], _where(where))
        self.blocks.append(block)
        name = params.get("ELSET")
        if name:
            self.wheres.setdefault(("ELSET", name), _where(where))
            self.elsets.setdefault(name, []).append(("block", len(self.blocks) - 1))
            if name not in self.element_sets:
                self.element_sets.append(name)
        return block

    def element_line(self, line: str, where: str, block):
        try:
            ints = _clamped([int(f) for f in line.split(",") if f and not f.isspace()])
        except ValueError:
            self.fail(where, f"cannot read {line[:60]!r} in *ELEMENT, TYPE={block[0]}, "
                             f"expected an element number and its node numbers")
        block[3].append((ints, where, line.endswith(",")))

    def surface(self, name: str, kind: str) -> Surface:
        """The surface that the data lines of ``*SURFACE, NAME=name, TYPE=kind`` go to. A name
        defined again adds lines to its surface; a node surface and an element surface may
        share a name in CalculiX (a contact pair takes the node one as its slave, the element
        one as its master): the element one is the zone, the node one's lines are dropped."""
        old = self.surfaces.get(name)
        if old is None or (old.type == "NODE" and kind == "ELEMENT"):
            self.surfaces[name] = Surface(name, kind)
            return self.surfaces[name]
        return old if old.type == kind else Surface(name, kind)  # dropped

    def surface_line(self, line: str, where: str, surface: Surface):
        fields = [f.strip() for f in line.split(",")]
        ref = fields[0].strip('"')
        if not ref:
            self.fail(where, f"cannot read {line[:60]!r} in *SURFACE, expected an element or "
                             f"node number or set name first")
        surface.lines.append((ref, fields[1] if len(fields) > 1 else "", _where(where)))


@functools.lru_cache(maxsize=2)
def _parse(path: str, mtime: int, size: int) -> Deck:
    r = _Reader(path)
    lines = _Lines(path)
    keyword, params, target = None, {}, None
    for line, number in lines:
        where = lines.at(number)
        if line.startswith("*"):
            keyword, params = _keyword(line), _params(line)
            target = None
            if keyword == "INCLUDE":
                lines.include(params.get("INPUT", ""), _where(where))
                keyword = None  # its data lines (none) are skipped
                continue
            if keyword == "NODE":
                target = (r.add_set(r.nsets, "NSET", params["NSET"], where)
                          if params.get("NSET") else None)
            elif keyword == "ELEMENT":
                target = r.element_block(params, where)
            elif keyword in ("NSET", "ELSET"):
                sets = r.nsets if keyword == "NSET" else r.elsets
                target = r.add_set(sets, keyword, params.get(keyword, ""), where)
                if keyword == "ELSET" and params[keyword] not in r.elset_order:
                    r.elset_order.append(params[keyword])
            elif keyword == "SURFACE":
                name = params.get("NAME", "")
                if not name:
                    r.fail(where, "*SURFACE without NAME=, expected *SURFACE, NAME=...")
                kind = " ".join((params.get("TYPE") or "ELEMENT").split()).upper()
                target = r.surface(name, kind)
            if keyword in _READ and params.get("INPUT"):  # the data lines are in a file
                lines.include(params["INPUT"], _where(where))
            continue
        if keyword == "NODE":
            r.node(line, where, target)
        elif keyword == "ELEMENT":
            r.element_line(line, where, target)
        elif keyword in ("NSET", "ELSET"):
            r.set_line(line, where, keyword, target, "GENERATE" in params)
        elif keyword == "SURFACE":
            r.surface_line(line, where, target)
    return _deck(r, lines.files)


def _deck(r: _Reader, files: list) -> Deck:
    numbers = np.array(r.node_numbers, dtype=np.int64)
    points = np.array(r.coords, dtype=np.float64).reshape(-1, 3)
    blocks = []
    for etype, kind, size, rows, where in r.blocks:
        blocks.append(_block(r, numbers, etype, kind, size, rows, where))
    all_numbers = np.concatenate([b.numbers for b in blocks]) if blocks else np.zeros(0, int)
    uniq, counts = np.unique(all_numbers, return_counts=True)
    if np.any(counts > 1):
        twice = int(uniq[np.argmax(counts > 1)])
        at = [b.where for b in blocks if twice in b.numbers]
        r.fail(at[-1], f"element {twice} is defined twice (also in the *ELEMENT at "
                       f"{at[0]}), expected each element number once")
    order = r.elset_order + [n for n in r.element_sets if n not in r.elset_order]
    return Deck(r.path, numbers, points, blocks, r.nsets, r.elsets, order, r.surfaces, files,
                r.wheres)


def _block(r: _Reader, numbers, etype, kind, size, rows, where) -> Block:
    """A block's element numbers and connectivity from its data lines, read as CalculiX reads
    them (elements.f): each element starts a line, its nodes run on to the next lines until
    it has all, and the numbers a line has beyond them are left out."""
    if size is None:  # a type of unknown size: one element per line, a comma continues it
        count = sum(1 for _, _, more in rows if not more) + (1 if rows and rows[-1][2] else 0)
        return Block(etype, None, np.zeros(0, np.int64), np.zeros((0, 0), np.int64), where,
                     count)
    elements, starts = [], []
    need = 0
    for ints, at, _ in rows:
        if need == 0:
            if not ints:
                r.fail(at, f"*ELEMENT, TYPE={etype}: a data line without an element number")
            elements.append(ints[:size + 1])
            starts.append(at)
            need = size + 1 - len(elements[-1])
        else:
            elements[-1] += ints[:need]
            need = size + 1 - len(elements[-1])
    if need:
        r.fail(starts[-1], f"*ELEMENT, TYPE={etype}: element {elements[-1][0]} has "
                           f"{len(elements[-1]) - 1} nodes, expected {size}")
    # numbers beyond int64 are clamped by element_line: out of range all the same
    data = np.array(elements, dtype=np.int64).reshape(-1, size + 1)
    ids = data[:, 0]
    bad = (ids <= 0) | (ids > _NUMBER_MAX)
    if bad.any():
        i = int(np.argmax(bad))
        r.fail(starts[i], f"element number {_shown(ids[i])}, expected 1 to {_NUMBER_MAX}")
    if kind is None:
        return Block(etype, None, ids, np.zeros((0, size), np.int64), where)
    conn = _lookup(numbers, np.arange(len(numbers)), data[:, 1:].reshape(-1)).reshape(-1, size)
    if np.any(conn < 0):
        i, j = np.argwhere(conn < 0)[0]
        r.fail(starts[i], f"element {int(ids[i])} refers to node {_shown(data[i, 1 + j])}, "
                          f"which the deck does not define")
    return Block(etype, kind, ids, conn, where)


def _shown(number) -> str:
    number = int(number)
    return str(number) if abs(number) < _CLAMP else f"beyond {_NUMBER_MAX}"


# --------------------------------------------------------------------------------------------
# the deck as a meshio mesh, and the decks meshio misreads
# --------------------------------------------------------------------------------------------


@dataclass
class CellBlock:
    """A block of cells, as meshio.CellBlock (whose types lack wedge15 in meshio 5.3)."""

    type: str
    data: np.ndarray
    dim: int


@dataclass
class DeckMesh:
    """A deck as the meshio.Mesh attributes that `mesh.read_target` reads."""

    points: np.ndarray
    cells: list
    point_sets: dict
    cell_sets: dict
    cell_data: dict = field(default_factory=dict)
    field_data: dict = field(default_factory=dict)
    point_data: dict = field(default_factory=dict)


_DIM = {k: 1 if k.startswith("line") else 3 if k.startswith(("tetra", "wedge", "hexa")) else 2
        for k in _NODES}


def deck_mesh(deck: Deck):
    """(the deck's points, cell blocks and sets as meshio's reader gives those of a deck it
    reads (a `DeckMesh`); element type -> number of elements read past (no meshio cell
    type))."""
    kept = [i for i, b in enumerate(deck.blocks) if b.kind is not None]
    cells = [(deck.blocks[i].kind, deck.blocks[i].conn) for i in kept]
    ignored = {}
    for b in deck.blocks:
        if b.kind is None:
            ignored[b.etype] = ignored.get(b.etype, 0) + len(b)
    point_sets = {name: deck.node_set(name) for name in deck.nsets}
    cell_sets = {}
    for name in deck.elset_order:
        members = deck.element_set(name)
        block, row = deck.element_index(members)
        cell_sets[name] = [np.sort(row[block == i]) for i in kept]
    if deck.skipped:  # as CalculiX, which warns
        _log.info("%s: numbers that name no node or element of the deck left out of %s",
                  deck.path, ", ".join(f"{kind} {name!r} ({n})"
                                       for (kind, name), n in deck.skipped.items()))
    mesh = DeckMesh(deck.points, [CellBlock(k, c, _DIM[k]) for k, c in cells], point_sets,
                    cell_sets)
    return mesh, ignored


def read_past(deck: Deck, name: str) -> dict:
    """Element type -> number of the elements of element set ``name`` read past (no meshio
    cell type: springs, masses, ...)."""
    if name not in deck.elsets:
        return {}
    block, _ = deck.element_index(deck.element_set(name))
    out = {}
    for b in block[block >= 0].tolist():
        if deck.blocks[b].kind is None:
            out[deck.blocks[b].etype] = out.get(deck.blocks[b].etype, 0) + 1
    return out


def meshio_misreads(path: str) -> str | None:
    """Why meshio's reader (5.3) would misread the deck ``path`` without failing (a few
    words), or None: a scan of its lines for what that reader gets wrong silently, checked on
    CalculiX's test decks (tests/test_decks.py): an *INCLUDE (its sets and surfaces lost, its
    nodes numbered apart); several *NODE blocks (all but the last lost, earlier elements
    pointing at other points); a comment line inside the data of *NODE, *ELEMENT, *NSET or
    *ELSET (the data lines after it lost); a set name inside a set (left out, or nested
    wrongly); a set defined twice (the first definition lost); an element set given to
    several *ELEMENT blocks, to some blocks but not to an earlier one, or also defined by
    *ELSET (its elements put in the wrong block); an element line with more nodes than its
    type has (the elements after it shifted). Missing or unreadable: None (the reader says
    why)."""
    try:
        with open(path, "rb") as f:
            text = f.read().decode("utf-8", errors="replace")
    except OSError:
        return None
    keyword, size, comment = None, None, False
    nodes, blocks, elsets, nsets, set_keywords = 0, [], set(), set(), set()
    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            continue
        if line.startswith("**"):
            comment = keyword in ("NODE", "ELEMENT", "NSET", "ELSET")
            continue
        if line.startswith("*"):
            keyword, params, comment = _keyword(line), _params(line), False
            if keyword == "INCLUDE":
                return "it has *INCLUDE"
            if keyword == "NODE":
                nodes += 1
                if nodes > 1:
                    return "it has several *NODE blocks"
            elif keyword == "ELEMENT":
                kind = CELL_TYPES.get(params.get("TYPE", "").upper())
                size = _NODES[kind] if kind else None
                name = params.get("ELSET") or None
                if name is not None and (None in blocks or name in blocks
                                         or name in set_keywords):
                    return f"its element set {name!r} is given to *ELEMENT blocks as it reads " \
                           f"them wrongly"
                blocks.append(name)
            elif keyword in ("NSET", "ELSET"):
                name = params.get(keyword, "")
                seen = nsets if keyword == "NSET" else elsets
                if name in seen or (keyword == "ELSET" and name in blocks):
                    return f"it defines the set {name!r} twice"
                seen.add(name)
                set_keywords.add(name) if keyword == "ELSET" else None
            continue
        if comment:
            return f"it has a comment line inside *{keyword} data"
        if keyword in ("NSET", "ELSET"):
            if any(f.strip() and not f.strip().isdigit() for f in line.split(",")):
                return "it names sets inside sets"
        elif keyword == "ELEMENT" and size is not None:
            if sum(1 for f in line.split(",") if f.strip()) > size + 1:
                return "an element line has more nodes than its type"
    return None
