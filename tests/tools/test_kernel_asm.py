"""clphong.tools.kernel_asm: the lights loop is found in PoCL's disassembly."""

from __future__ import annotations

import shutil

import pytest

from clphong.core.errors import ClphongError
from clphong.tools import kernel_asm

BODY = "\n".join(f"  {0x1100 + 4 * i:x}:\tvfmadd231ps %zmm1,%zmm2,%zmm3" for i in range(32))
OBJDUMP = f"""
0000000000001000 <_Z7_cl_allDv16_i>:
    1000:\tret
0000000000001080 <_pocl_kernel_shade>:
    1080:\tvmulps %zmm0,%zmm0,%zmm0
{BODY}
    1180:\tvmovaps 0x40(%rsp),%zmm4
    1188:\tcall   1000 <_Z7_cl_allDv16_i>
    1190:\tvdivps %zmm2,%zmm1,%zmm1
    1198:\tjne    1100 <_pocl_kernel_shade+0x80>
    11a0:\tjmp    1080 <_pocl_kernel_shade>
0000000000002000 <_pocl_kernel_shade_workgroup>:
    2000:\tret
"""


def test_the_smallest_loop_with_enough_multiplies_is_the_lights_loop():
    loop = kernel_asm.lights_loop(kernel_asm.parse_objdump(OBJDUMP))
    s = kernel_asm.summary(loop)
    # 1100 .. 1198: the 32 FMAs, the spill, the call, the division, the jump
    assert s["instructions"] == 36 and s["stack_references"] == 1
    assert s["calls"] == 1 and s["divisions"] == 1
    text = kernel_asm.mca_input(loop)
    assert "call" not in text and "jne" not in text and "<" not in text


def test_no_loop_is_an_error():
    with pytest.raises(ClphongError, match="no lights loop"):
        kernel_asm.lights_loop(kernel_asm.parse_objdump(OBJDUMP.replace("vfmadd231ps", "vaddps")))
    with pytest.raises(ClphongError, match="no function"):
        kernel_asm.parse_objdump("nothing here")


def _elf(body: bytes, shoff: int, shentsize: int = 64, shnum: int = 3) -> bytes:
    head = bytearray(64)
    head[:4] = b"\x7fELF"
    head[0x28:0x30] = shoff.to_bytes(8, "little")
    head[0x3A:0x3C] = shentsize.to_bytes(2, "little")
    head[0x3C:0x3E] = shnum.to_bytes(2, "little")
    return bytes(head) + body


def test_the_kernel_object_is_cut_from_the_program_binary_at_its_section_table_end():
    elf = _elf(b"x" * (100 - 64 + 3 * 64), shoff=100)
    assert len(elf) == 100 + 3 * 64
    blob = b"poclbin\x00" + b"\x01" * 37 + elf + b"program.bc and more"
    assert kernel_asm.elf_in(blob) == elf
    with pytest.raises(ClphongError, match="no single kernel object"):
        kernel_asm.elf_in(b"poclbin\x00 nothing")
    with pytest.raises(ClphongError, match="no single kernel object"):
        kernel_asm.elf_in(blob + elf)
    with pytest.raises(ClphongError, match="cut short"):
        kernel_asm.elf_in(b"poclbin\x00" + elf[:150])


def _elf_with_sections(sections: dict[str, bytes]) -> bytes:
    """An ELF64 file with these sections (and a section-name table), as Intel's CPU
    runtime writes its program binary."""
    names = b"\0" + b"".join(n.encode() + b"\0" for n in sections) + b".shstrtab\0"
    body, offsets, at = b"", [], 64
    for data in [*sections.values(), names]:
        offsets.append((at, len(data)))
        body += data
        at += len(data)
    heads = [bytes(64)]
    name_at = 1
    for (off, size), n in zip(offsets, [*sections, ".shstrtab"]):
        h = bytearray(64)
        h[0:4] = name_at.to_bytes(4, "little")
        h[0x18:0x20] = off.to_bytes(8, "little")
        h[0x20:0x28] = size.to_bytes(8, "little")
        heads.append(bytes(h))
        name_at += len(n) + 1
    head = bytearray(64)
    head[:6] = b"\x7fELF\x02\x01"                 # ELF64, little-endian
    head[0x28:0x30] = at.to_bytes(8, "little")
    head[0x3A:0x3C] = (64).to_bytes(2, "little")
    head[0x3C:0x3E] = len(heads).to_bytes(2, "little")
    head[0x3E:0x40] = (len(heads) - 1).to_bytes(2, "little")
    return bytes(head) + body + b"".join(heads)


def test_intels_kernel_object_is_its_binarys_ocl_obj_section():
    blob = _elf_with_sections({".ocl.ir": b"IR" * 10, ".ocl.obj": b"\x7fELF object", ".ocl.ver": b"1"})
    assert kernel_asm.section(blob, ".ocl.obj") == b"\x7fELF object"
    assert kernel_asm.section(blob, ".ocl.ver") == b"1"
    with pytest.raises(ClphongError, match="no section .ocl.meta"):
        kernel_asm.section(blob, ".ocl.meta")
    with pytest.raises(ClphongError, match="not an ELF file"):
        kernel_asm.section(b"poclbin\0", ".ocl.obj")
    with pytest.raises(ClphongError, match="64-bit little-endian"):
        kernel_asm.section(blob[:4] + b"\x01" + blob[5:], ".ocl.obj")
    with pytest.raises(ClphongError, match="no readable section table"):
        kernel_asm.section(blob[:-40], ".ocl.obj")


LISTING = "\n".join([
    "\t.text", "shade:", "\tvmulps %ymm0, %ymm0, %ymm0",
    ".LBB0_3:                # the lights loop", *["\tvfmadd231ps %ymm1, %ymm2, %ymm3"] * 31,
    "\tcmpq %rax, %rcx", "\tjne .LBB0_3", "# %bb.4:", "\tretq"])


def test_an_assembler_listing_has_its_jumps_turned_to_addresses():
    """numba's listing (labels, no addresses) goes through the same loop finder."""
    ins = kernel_asm.parse_listing(LISTING)
    assert ins[1] == (1, "vfmadd231ps %ymm1, %ymm2, %ymm3")
    assert ins[33] == (33, "jne 1")
    loop = kernel_asm.lights_loop(ins)
    assert len(loop) == 33 and loop[0].startswith("vfmadd") and loop[-1] == "jne 1"


def test_each_modules_labels_are_its_own():
    """numba prints a listing per module between banners, and LLVM's local labels repeat
    across them: the first module's loop stays a backward jump to its own label."""
    banner = "-" * 20 + "ASSEMBLY nrt" + "-" * 20
    other = "\n".join(["\t.text", ".LBB0_3:", "\tvaddps %ymm0, %ymm0, %ymm0", "\tjne .LBB0_3"])
    ins = kernel_asm.parse_listing(LISTING + "\n" + banner + "\n" + other)
    assert ins[33] == (33, "jne 1")                 # not the second module's .LBB0_3
    assert ins[-1] == (len(ins) - 1, f"jne {len(ins) - 2:x}")
    loop = kernel_asm.lights_loop(ins)
    assert len(loop) == 33


def test_a_jump_to_a_symbol_is_not_an_address():
    """`jmp cfunc` does not read as a jump to 0xcf (a false backward loop)."""
    ins = [(0x1000 + i, "vmulps %ymm0, %ymm0, %ymm0") for i in range(40)] + [(0x2000, "jmp cfunc")]
    with pytest.raises(ClphongError, match="no lights loop"):
        kernel_asm.lights_loop(ins)


def test_the_busiest_resources_come_first():
    report = "\n".join([
        "Resources:", "[0]   - Zn3FPP0", "[1]   - Zn3FPP1", "[2.0] - Zn3LSU", "", "",
        "Resource pressure per iteration:", "[0]    [1]    [2.0]",
        " 141.88 156.13  -", "", "Resource pressure by instruction:"])
    assert kernel_asm.pressure(report) == [("Zn3FPP1", 156.13), ("Zn3FPP0", 141.88)]
    assert kernel_asm.pressure("nothing") == []


@pytest.mark.skipif(shutil.which("objdump") is None, reason="needs objdump")
@pytest.mark.parametrize("platform", ["pocl", "intel"])
@pytest.mark.parametrize("path", ["fast", "accurate"])
def test_real_kernel_has_a_lights_loop_in_the_paths_format(path, platform):
    """The loop is the frame's own program's: in double on the accurate path (where the
    device has fp64, as both CPU platforms have), in float on the fast one (the newest
    kernel object in PoCL's cache, which the tool used to read, was a self-test's float
    variant on both). PoCL 3.0 calls some builtins out of line (rsqrt, isinf, copysign),
    spilling every vector register around the call once per light: its lights loop has
    none. (Intel's runtime calls its builtin rsqrt where the plan takes it: Zen 3's fast
    path.)"""
    try:
        text = kernel_asm.build_and_disassemble(path, device=platform)
    except ClphongError as exc:          # not this platform's CPU device here
        pytest.skip(str(exc))
    s = kernel_asm.summary(kernel_asm.lights_loop(kernel_asm.parse_objdump(text)))
    assert s["instructions"] > 30
    assert (s["double_ops"] > 30) == (path == "accurate")
    if platform == "pocl":
        assert s["calls"] == 0
