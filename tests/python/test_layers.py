"""The core's layers as core/CMakeLists.txt declares them, held against every #include.

core/<layer>/ is one library, declared by `dhr_layer(<layer> DEPS <layers below> ...)`. A file
of a layer may include headers of its own layer and of the layers its DEPS reach (transitively);
the backends (backends/) those that dhr_backends links; the command line (experiments/) and the
tests any. Embree's headers reach no file outside core/trace/ and the tests. Every path a source,
script or doc cites exists. Run with --stats to print the structure's figures (include edges by
layer, sources that see Embree, what the live relay includes).
"""

import functools
import os
import re
import subprocess
import sys
import unittest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
INCLUDE = re.compile(r'^\s*#\s*include\s+"((?:core|backends|experiments|tests)/[^"]+)"', re.M)
SYSTEM_INCLUDE = re.compile(r"^\s*#\s*include\s+<([^>]+)>", re.M)
SOURCE_EXT = (".h", ".cpp")


@functools.lru_cache(maxsize=None)
def read(path):
    """A file of the tree, read once per process (the checks below read most files twice)."""
    with open(os.path.join(ROOT, path), encoding="utf-8") as f:
        return f.read()


def parse_layers(cmake_text):
    """{layer: [direct deps]} from the dhr_layer() calls, in declaration order."""
    layers = {}
    for m in re.finditer(r"^dhr_layer\(([^)]*)\)", cmake_text, re.M):
        words = m.group(1).split()
        name, deps, mode = words[0], [], None
        for w in words[1:]:
            if w in ("DEPS", "PUBLIC", "PRIVATE"):
                mode = w
            elif mode == "DEPS":
                deps.append(w)
        if name in layers:
            raise ValueError(f"core/CMakeLists.txt declares layer {name} twice")
        for d in deps:
            if d not in layers:
                raise ValueError(f"layer {name} depends on {d}, which is not declared before it")
        layers[name] = deps
    return layers


def closure(layers):
    """{layer: set of layers it may use}, its own included."""
    out = {}
    for name, deps in layers.items():  # declaration order: deps are done first
        reach = {name}
        for d in deps:
            reach |= out[d]
        out[name] = reach
    return out


def sources(folder):
    for dirpath, _, names in os.walk(os.path.join(ROOT, folder)):
        for n in sorted(names):
            if n.endswith(SOURCE_EXT):
                yield os.path.relpath(os.path.join(dirpath, n), ROOT)


def includes(path):
    return INCLUDE.findall(read(path))


def layer_of(path):
    """The core layer a path belongs to, or None outside core/."""
    parts = path.split("/")
    return parts[1] if parts[0] == "core" and len(parts) == 3 else None


def violations(files, allowed, backends_allowed):
    """Edges the table does not allow: (file, included header, why).

    files: {path: [included project headers]}; allowed: closure(); backends_allowed: layers."""
    bad = []
    for path, incs in files.items():
        own = layer_of(path)
        if path.startswith("core/") and own not in allowed:
            bad.append((path, "", "a core file outside the declared layer folders"))
            continue
        for inc in incs:
            target = layer_of(inc)
            if path.startswith("core/"):
                if target is None:
                    bad.append((path, inc, "the core includes nothing outside core/<layer>/"))
                elif target not in allowed[own]:
                    bad.append((path, inc, f"layer {own} may use {sorted(allowed[own])}"))
            elif path.startswith("backends/"):
                if inc.startswith("backends/"):
                    continue
                if target is None or target not in backends_allowed:
                    bad.append((path, inc, f"backends may use {sorted(backends_allowed)}"))
    return bad


def project_files():
    files = {}
    for folder in ("core", "backends", "experiments", "tests"):
        for p in sources(folder):
            files[p] = includes(p)
    return files


def embree_seers(files):
    """The project files that include <embree3/...> directly or through project headers."""
    direct = {p for p in files if any(i.startswith("embree3/") for i in SYSTEM_INCLUDE.findall(read(p)))}
    seers = set(direct)
    changed = True
    while changed:
        changed = False
        for p, incs in files.items():
            if p not in seers and any(i in seers for i in incs):
                seers.add(p)
                changed = True
    return seers


def transitive_includes(files, start):
    seen, todo = set(), list(files.get(start, []))
    while todo:
        h = todo.pop()
        if h in seen or h not in files:
            continue
        seen.add(h)
        todo.extend(files[h])
    return seen


def backends_layers(allowed):
    text = read("backends/CMakeLists.txt")
    m = re.search(r"target_link_libraries\(dhr_backends\s+PUBLIC((?:\s+dhr_\w+)+)", text)
    if not m:
        raise ValueError("backends/CMakeLists.txt: no `target_link_libraries(dhr_backends PUBLIC dhr_...)`")
    out = set()
    for lib in m.group(1).split():
        out |= allowed[lib[len("dhr_"):]]
    return out


# Paths that the docs' worked examples create (docs/adding-a-backend.md, docs/architecture.md).
EXAMPLE_FILES = {"backends/denoise/box3.cpp", "backends/codec/brotli.cpp", "core/pass/trace_sky.cpp"}
CITED = re.compile(r"(?<![\w/.$-])((?:core|backends|experiments|tests|docs|scripts)/[\w./-]*\.(?:h|cpp|md|py|sh|json|patch|txt|js))\b")


def missing_citations():
    """(file, line, path) for each path a source, script or doc names that does not exist.

    CHANGELOG.md (history) and reports/ (published results) are not read; placeholders in
    capitals (experiments/NAME.json) and the examples' new files are not citations."""
    tracked = subprocess.run(["git", "-C", ROOT, "ls-files"], capture_output=True, text=True, check=True).stdout.split()
    out = []
    for p in tracked:
        if p.startswith("reports/") or p == "CHANGELOG.md" or p == "tests/python/test_layers.py":
            continue
        if not (p.endswith((".h", ".cpp", ".md", ".py", ".sh", ".txt", ".js")) or p.endswith("CMakeLists.txt")):
            continue
        for n, line in enumerate(read(p).split("\n"), 1):
            for m in CITED.finditer(line):
                f = m.group(1)
                if "NAME" in f or f in EXAMPLE_FILES or os.path.exists(os.path.join(ROOT, f)):
                    continue
                out.append((p, n, f))
    return out


class Layers(unittest.TestCase):
    def setUp(self):
        self.layers = parse_layers(read("core/CMakeLists.txt"))
        self.allowed = closure(self.layers)
        self.files = project_files()

    def test_every_folder_is_a_declared_layer(self):
        folders = sorted(d for d in os.listdir(os.path.join(ROOT, "core")) if os.path.isdir(os.path.join(ROOT, "core", d)))
        self.assertEqual(folders, sorted(self.layers))

    def test_every_include_exists(self):
        missing = [(p, i) for p, incs in self.files.items() for i in incs if not os.path.exists(os.path.join(ROOT, i))]
        self.assertEqual(missing, [])

    def test_no_include_runs_upward(self):
        bad = violations(self.files, self.allowed, backends_layers(self.allowed))
        self.assertEqual(bad, [], "\n".join(f"{p} -> {i}: {why}" for p, i, why in bad))

    def test_the_check_sees_an_upward_edge(self):
        # The raster layer including the simulator: an edge the table does not allow.
        files = {"core/raster/raster.cpp": ["core/sim/frame_loop.h"],
                 "backends/codec/raw.cpp": ["core/trace/trace.h"],
                 "core/loose.h": []}
        self.assertEqual(len(violations(files, self.allowed, backends_layers(self.allowed))), 3)

    def test_embree_stays_in_the_tracer(self):
        outside = sorted(p for p in embree_seers(self.files)
                         if not p.startswith("core/trace/") and not p.startswith("tests/"))
        self.assertEqual(outside, [])

    def test_cited_files_exist(self):
        if not os.path.isdir(os.path.join(ROOT, ".git")) and not os.path.isfile(os.path.join(ROOT, ".git")):
            self.skipTest("not a git checkout")
        bad = missing_citations()
        self.assertEqual(bad, [], "\n".join(f"{p}:{n}: {f} does not exist" for p, n, f in bad))

    def test_the_relay_does_not_see_the_tracer_or_the_simulator(self):
        seen = transitive_includes(self.files, "core/live/live_relay.cpp")
        reached = sorted({layer_of(h) for h in seen} & {"trace", "raster", "sim", "pipeline", "metrics"})
        self.assertEqual(reached, [])


def stats():
    layers = parse_layers(read("core/CMakeLists.txt"))
    files = project_files()
    allowed = closure(layers)
    nontest = [p for p in files if not p.startswith("tests/")]
    seers = embree_seers(files)
    print(f"layers: {len(layers)}; core files: {sum(1 for p in files if p.startswith('core/'))}")
    print(f"upward include edges: {len(violations(files, allowed, backends_layers(allowed)))}")
    print(f"non-test sources that see Embree: {len([p for p in nontest if p in seers])} of {len(nontest)}")
    relay = transitive_includes(files, "core/live/live_relay.cpp")
    print(f"project headers the live relay includes: {len(relay)}")
    for name, deps in layers.items():
        print(f"  {name:10s} -> {' '.join(deps) if deps else '(none)'}")


if __name__ == "__main__":
    if "--stats" in sys.argv:
        stats()
        sys.exit(0)
    unittest.main()
