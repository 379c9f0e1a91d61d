"""What bounds the shading kernel: its lights loop as PoCL compiled it.

``python -m clphong.tools.kernel_asm [--path accurate] [--cpu icelake-server] [--mca]``

Builds the bench scene's shading kernel (:mod:`clphong.tools.bench`, 4 point
lights: the same variant as any light count) in a fresh PoCL cache, disassembles
the program the bench frame used (its kernel object, cut from the platform's program
binary) with ``objdump``, and finds the lights loop (the smallest backward-jumping
block of the kernel's function with at least 30 vector multiplies). It prints the
instructions one light costs a work-item (LANES pixels), the stack references among
them (spills), the calls (PoCL 3.0 calls some builtins out of line, which spills every
vector register), the divisions and square roots, and the double operations. With ``--mca`` (``llvm-mca``, Debian's ``llvm``
package, the LLVM PoCL uses), the simulated cycles per light for ``--cpu`` and
its bottleneck analysis: resource pressure per port against register
dependencies (the critical path). Not a test; a tool for kernel work
(docs/bench.md, "What bounds the kernel").
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

from ..core.errors import ClphongError

#: What a lights loop must hold to be taken for it (the work-item loop holds more).
MIN_MULTIPLIES = 30


#: The shading kernel's function: PoCL's (``shade.so``), then Intel's runtime's (its object).
KERNEL_FUNCTIONS = ("_pocl_kernel_shade", "shade")


def parse_objdump(text: str, function: str | None = None) -> list[tuple[int, str]]:
    """(address, instruction) of ``function`` (the first of :data:`KERNEL_FUNCTIONS` found
    when None) in ``objdump -d --no-show-raw-insn`` output."""
    lines = text.splitlines()
    names = (function,) if function else KERNEL_FUNCTIONS
    start = next((i for name in names for i, ln in enumerate(lines) if ln.endswith(f"<{name}>:")), None)
    if start is None:
        raise ClphongError(f"no function {' or '.join(names)} in the disassembly")
    out = []
    for ln in lines[start + 1:]:
        if ln.endswith(">:"):
            break
        m = re.match(r"\s*([0-9a-f]+):\s+(.*)$", ln)
        if m:
            out.append((int(m.group(1), 16), m.group(2).split("#")[0].strip()))
    return out


def parse_listing(text: str) -> list[tuple[int, str]]:
    """(index, instruction) of an assembler listing with labels (LLVM's ``.s``, as numba's
    ``NUMBA_DUMP_ASSEMBLY`` prints it): directives and comments dropped, and each jump to
    a label rewritten as a jump to its instruction's index (hex), as objdump gives it.
    Labels are resolved within their own module: numba prints one listing per module,
    between banner lines of ``-`` or ``=``, and LLVM's local labels (``.LBB0_3``)
    repeat from one module to the next."""
    out: list[tuple[int, str]] = []
    module: list[tuple[int, str]] = []
    labels: dict[str, int] = {}

    def close():
        for i, t in module:
            m = re.match(r"(j\w+)\s+([.\w$]+)$", t)
            if m and m.group(2) in labels:
                t = f"{m.group(1)} {labels[m.group(2)]:x}"
            out.append((i, t))
        module.clear()
        labels.clear()

    n = 0
    for ln in text.splitlines():
        t = ln.split("#")[0].strip()
        if t.startswith(("=", "-")):          # a banner: the next module's listing
            close()
            continue
        m = re.match(r"^([.\w$]+):", t)
        if m:
            labels[m.group(1)] = n
            t = t[m.end():].strip()
        if not t or t.startswith("."):
            continue
        module.append((n, " ".join(t.split())))
        n += 1
    close()
    return out


def lights_loop(instructions: list[tuple[int, str]]) -> list[str]:
    """The lights loop's instructions: the smallest block ending in a backward jump
    that holds at least :data:`MIN_MULTIPLIES` vector multiplies or FMAs."""
    loops = []
    for addr, text in instructions:
        m = re.match(r"j\w+\s+([0-9a-f]+)(?:\s|$)", text)
        if m and int(m.group(1), 16) < addr:
            target = int(m.group(1), 16)
            loops.append([t for a, t in instructions if target <= a <= addr])
    found = [blk for blk in loops
             if sum(1 for t in blk if re.match(r"v(fn?m(add|sub)\w*|mul)p[sd]", t)) >= MIN_MULTIPLIES]
    if not found:
        raise ClphongError("no lights loop found in the disassembly")
    return min(found, key=len)


def summary(loop: list[str]) -> dict:
    """Counts of one lights-loop iteration."""
    return {
        "instructions": sum(1 for t in loop if not t.startswith(("nop", "data16", "cs "))),
        # through the stack pointer, the frame pointer, or %rbx where LLVM realigns the
        # frame (PoCL's 32-byte-aligned spill slots); the light records are indexed
        "stack_references": sum(1 for t in loop if re.search(r"\(%r(?:sp|bp|bx)\)", t)),
        "calls": sum(1 for t in loop if t.startswith("call")),
        "divisions": sum(1 for t in loop if re.match(r"vdivp[sd]", t)),
        "square_roots": sum(1 for t in loop if re.match(r"vsqrtp[sd]", t)),
        "rsqrt_estimates": sum(1 for t in loop if re.match(r"vrsqrt(14)?p[sd]", t)),
        "conversions": sum(1 for t in loop if re.match(r"vcvt", t)),
        "double_ops": sum(1 for t in loop if re.match(r"v\w+pd\b", t) and not t.startswith("vmov")),
    }


def mca_input(loop: list[str]) -> str:
    """The loop as straight-line code for llvm-mca (no jumps, calls or symbols)."""
    keep = [re.sub(r"\s*<[^>]*>", "", t) for t in loop
            if not t.startswith(("j", "call", "nop", "data16", "cs "))]
    return "\n".join(keep) + "\n"


def run_mca(loop: list[str], cpu: str, iterations: int = 300) -> tuple[float, str]:
    """(cycles per iteration, llvm-mca's report) for ``cpu``."""
    exe = shutil.which("llvm-mca")
    if exe is None:
        raise ClphongError("llvm-mca not found: install LLVM's tools (Debian: apt-get install llvm)")
    res = subprocess.run([exe, f"-mcpu={cpu}", f"-iterations={iterations}", "-bottleneck-analysis"],
                         input=mca_input(loop), capture_output=True, text=True)
    if res.returncode != 0:
        raise ClphongError(f"llvm-mca failed: {res.stderr.strip().splitlines()[0] if res.stderr else res.returncode}")
    total = re.search(r"Total Cycles:\s+([0-9]+)", res.stdout)
    return int(total.group(1)) / iterations, res.stdout


def pressure(report: str) -> list[tuple[str, float]]:
    """llvm-mca's resource pressure per iteration (cycles each resource is busy a light),
    busiest first: the busiest one bounds the cycles a light from below, on its model."""
    names = re.findall(r"^\[([0-9.]+)\]\s+-\s+(\S+)", report, re.M)
    at = report.find("Resource pressure per iteration:")
    if at < 0 or not names:
        return []
    rows = report[at:].splitlines()
    values = rows[2].split() if len(rows) > 2 else []
    # a resource with several units (Zn3FPP45 twice) is named by its index too
    count = {name: sum(1 for _, n in names if n == name) for _, name in names}
    out = [(name if count[name] == 1 else f"{name}[{index}]", float(v))
           for (index, name), v in zip(names, values) if v != "-"]
    return sorted(out, key=lambda nv: -nv[1])


def section(blob: bytes, name: str) -> bytes:
    """The contents of section ``name`` of an ELF64 file (Intel's CPU runtime ships its
    program binary as one: ``.ocl.ir``, ``.ocl.meta``, ``.ocl.obj`` with the x86 object)."""
    if blob[:4] != b"\x7fELF":
        raise ClphongError("the program's binary is not an ELF file (not Intel's CPU runtime?)")
    if blob[4:6] != b"\x02\x01":
        raise ClphongError("the program's binary is not a 64-bit little-endian ELF file")
    u = lambda at, n: int.from_bytes(blob[at:at + n], "little")  # noqa: E731
    shoff, shentsize, shnum, shstrndx = u(0x28, 8), u(0x3A, 2), u(0x3C, 2), u(0x3E, 2)
    heads = [shoff + k * shentsize for k in range(shnum)]
    if not shnum or shstrndx >= shnum or heads[-1] + 0x28 > len(blob):
        raise ClphongError("the program's binary has no readable section table")
    strtab = u(heads[shstrndx] + 0x18, 8)
    for h in heads:
        at = strtab + u(h, 4)
        end = blob.find(b"\0", at)
        if end < 0:
            raise ClphongError("the program's binary has a section name past its end")
        if blob[at:end].decode("latin-1") == name:
            off, size = u(h + 0x18, 8), u(h + 0x20, 8)
            if off + size > len(blob):
                raise ClphongError(f"the program's section {name} runs past its end")
            return blob[off:off + size]
    raise ClphongError(f"no section {name} in the program's binary")


def elf_in(blob: bytes) -> bytes:
    """The one ELF object inside a PoCL program binary (its kernel's ``.so``): from its
    magic to the end of its section header table, as the ELF64 header gives it."""
    start = blob.find(b"\x7fELF")
    if start < 0 or blob.find(b"\x7fELF", start + 4) >= 0:
        raise ClphongError("the program's binary holds no single kernel object (not PoCL's CPU device?)")
    head = blob[start:start + 64]
    shoff = int.from_bytes(head[0x28:0x30], "little")
    shentsize = int.from_bytes(head[0x3A:0x3C], "little")
    shnum = int.from_bytes(head[0x3C:0x3E], "little")
    end = shoff + shentsize * shnum
    if not shoff or not 64 <= end <= len(blob) - start:
        raise ClphongError("the kernel object in the program's binary is cut short")
    return blob[start:start + end]


#: The child's script: the bench frame shaded once, then the very program that frame used
#: (the renderer's own plan for it) written out as the platform's binary.
_CHILD = """
import sys
import pyopencl as cl
from clphong.tools import bench
from clphong.device.frame import has_far_lights, pack_lights
from clphong.device.renderer import Renderer, prepare_frame
o = dict(bench.PATHS[sys.argv[1]], device=sys.argv[4])
if sys.argv[2] != "0":
    o["lanes"] = int(sys.argv[2])
r = Renderer(bench.bench_scene("wide", 4), **o)
want = {"pocl": "pocl", "intel": "intel-cpu"}[sys.argv[4]]
if r.runtime.kind != want:
    sys.exit(f"--device {sys.argv[4]} matched a {r.runtime.kind} device, not {want}")
f = prepare_frame(bench.bench_gbuffer(128, 16), lanes=r.lanes)
r.shade(f)
far = has_far_lights(f, pack_lights(r.scene, f.origin))
_, prog = r._plan_and_program(f.map_names, coverage=f.coverage, far=far)
with open(sys.argv[3], "wb") as out:
    out.write(prog.get_info(cl.program_info.BINARIES)[0])
"""


#: The numba peer's child: its loop compiled for the bench scene (the same exponent).
_PEER_CHILD = """
from clphong.tools.bench_scenes import bench_gbuffer, bench_scene
from clphong.tools.numba_peer import NumbaPeer
NumbaPeer(bench_scene("wide", 4), bench_gbuffer(128, 16))
"""


def build_and_disassemble(path: str = "accurate", lanes: int | None = None,
                          device: str = "pocl") -> str:
    """Build the bench kernel for ``path`` on ``device`` (``pocl`` or ``intel``) in fresh
    caches; the objdump text of the program the frame used. (Not the newest ``shade.so``
    in PoCL's cache: the self-tests build other variants, some after the frame's.) PoCL's
    binary holds the kernel's ``.so``; Intel's runtime's is an ELF file whose ``.ocl.obj``
    section is the kernel's x86 object."""
    objdump = shutil.which("objdump")
    if objdump is None:
        raise ClphongError("objdump not found: install binutils")
    folder = tempfile.mkdtemp(prefix="clphong-asm-")
    try:
        binary = os.path.join(folder, "program.bin")
        # PoCL reads POCL_CACHE_DIR when it starts, so this runs in a fresh process;
        # clphong's own cache would hand back a built binary: PoCL would compile nothing
        env = dict(os.environ, POCL_CACHE_DIR=folder, CLPHONG_CACHE_DIR=os.path.join(folder, "clphong"))
        res = subprocess.run([sys.executable, "-c", _CHILD, path, str(int(lanes or 0)), binary, device],
                             env=env, capture_output=True, text=True)
        if res.returncode != 0:
            last = res.stderr.strip().splitlines()[-1] if res.stderr.strip() else f"exit {res.returncode}"
            raise ClphongError(f"building the kernel failed: {last}")
        with open(binary, "rb") as fh:
            blob = fh.read()
        obj = section(blob, ".ocl.obj") if blob[:4] == b"\x7fELF" else elf_in(blob)
        lib = os.path.join(folder, "shade.o")
        with open(lib, "wb") as fh:
            fh.write(obj)
        res = subprocess.run([objdump, "-d", "--no-show-raw-insn", lib], capture_output=True, text=True)
        if res.returncode != 0:
            raise ClphongError(f"objdump could not read the kernel object: {res.stderr.strip()[:200]}")
        return res.stdout
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def peer_listing() -> str:
    """The numba peer's assembly (``NUMBA_DUMP_ASSEMBLY``) for the bench scene, from a
    child process."""
    env = dict(os.environ, NUMBA_DUMP_ASSEMBLY="1")
    res = subprocess.run([sys.executable, "-c", _PEER_CHILD], env=env, capture_output=True, text=True)
    if res.returncode != 0:
        last = res.stderr.strip().splitlines()[-1] if res.stderr.strip() else f"exit {res.returncode}"
        raise ClphongError(f"compiling the numba peer failed (pip install 'clphong[bench]'): {last}")
    return res.stdout


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m clphong.tools.kernel_asm", description=__doc__.split("\n\n")[0])
    ap.add_argument("--path", default="accurate", help="a bench path (clphong.tools.bench.PATHS)")
    ap.add_argument("--device", default="pocl", choices=("pocl", "intel"),
                    help="the platform whose compiler is read (default: pocl)")
    ap.add_argument("--peer", action="store_true",
                    help="the numba peer's loop instead (8 px a light; --path, --lanes and --device do not apply)")
    ap.add_argument("--lanes", type=int, default=None, help="pixels per work-item (default: the device's)")
    ap.add_argument("--cpu", default="icelake-server", help="llvm-mca's CPU model (e.g. znver3)")
    ap.add_argument("--mca", action="store_true", help="simulate the loop with llvm-mca")
    ap.add_argument("--show", action="store_true", help="print the loop's instructions")
    args = ap.parse_args(argv)
    try:
        if args.peer:
            what = "numba peer"
            loop = lights_loop(parse_listing(peer_listing()))
        else:
            what = f"{args.path} on {args.device}"
            loop = lights_loop(parse_objdump(build_and_disassemble(args.path, args.lanes, args.device)))
        s = summary(loop)
        print(f"{what}: one light per work-item: " + ", ".join(f"{k.replace('_', ' ')} {v}"
                                                             for k, v in s.items()))
        if args.show:
            print("\n".join(loop))
        if args.mca:
            cycles, report = run_mca(loop, args.cpu)
            print(f"llvm-mca -mcpu={args.cpu}: {cycles:.1f} cycles a light")
            busiest = pressure(report)[:4]
            if busiest:
                print("busiest resources, cycles a light: " + ", ".join(f"{n} {v:.1f}" for n, v in busiest))
            head = report[report.find("Cycles with backend pressure"):]
            print(head[:head.find("Critical sequence")].rstrip())
    except ClphongError as exc:
        print(f"kernel_asm: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
