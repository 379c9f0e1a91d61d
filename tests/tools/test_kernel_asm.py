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


@pytest.mark.skipif(shutil.which("objdump") is None, reason="needs objdump")
@pytest.mark.parametrize("path", ["fast", "accurate"])
def test_real_kernel_has_a_lights_loop_without_calls(path):
    """PoCL 3.0 calls some builtins out of line (rsqrt, isinf, copysign), spilling
    every vector register around the call once per light: the lights loop has none.
    The loop is the frame's own program's: in double on the accurate path (where the
    device has fp64, as PoCL's CPU device has), in float on the fast one (the newest
    kernel object in PoCL's cache, which the tool used to read, was a self-test's
    float variant on both)."""
    try:
        text = kernel_asm.build_and_disassemble(path)
    except ClphongError as exc:          # not PoCL's CPU device
        pytest.skip(str(exc))
    s = kernel_asm.summary(kernel_asm.lights_loop(kernel_asm.parse_objdump(text)))
    assert s["calls"] == 0 and s["instructions"] > 30
    assert (s["double_ops"] > 30) == (path == "accurate")
