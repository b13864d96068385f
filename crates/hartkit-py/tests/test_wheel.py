"""The installed wheel is the portable one (docs/python.md, "Building the wheel"): an
abi3 manylinux wheel whose extension module carries its own OpenSSL, statically
linked, and needs nothing of the system but the manylinux libraries (libc, libm,
libgcc_s). And that OpenSSL works: HART-IP version 2 from Python to the CLI's server."""

import asyncio
import importlib.metadata
import re
import shutil
import struct
import subprocess

import pytest

import hartkit
import hartkit._native
from conftest import PSK

MODULE = hartkit._native.__file__


def elf_sections(data):
    """(type, link, info, bytes) of each section of a little-endian ELF64 file."""
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        pytest.skip(f"{MODULE} is not a little-endian ELF64 file")
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    sections = []
    for i in range(shnum):
        _, kind, _, _, off, size, link, info, _, _ = struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize)
        sections.append((kind, link, info, data[off : off + size]))
    return sections


def cstr(table, offset):
    return table[offset : table.index(b"\0", offset)].decode()


def needed_and_glibc(path):
    """The DT_NEEDED libraries of an ELF file and the GLIBC_x.y versions it asks for
    (its .dynamic and .gnu.version_r sections), read without any tool."""
    with open(path, "rb") as f:
        sections = elf_sections(f.read())
    needed, versions = [], set()
    for kind, link, info, body in sections:
        strings = sections[link][3]
        if kind == 6:  # SHT_DYNAMIC: (tag, value) pairs; DT_NEEDED is 1
            for tag, value in struct.iter_unpack("<qQ", body):
                if tag == 1:
                    needed.append(cstr(strings, value))
        elif kind == 0x6FFFFFFE:  # SHT_GNU_verneed: one entry per library, each with its versions
            at = 0
            for _ in range(info):
                _, count, _, aux, nxt = struct.unpack_from("<HHIII", body, at)
                a = at + aux
                for _ in range(count):
                    _, _, _, name, anext = struct.unpack_from("<IHHII", body, a)
                    m = re.fullmatch(r"GLIBC_(\d+)\.(\d+)(?:\.\d+)?", cstr(strings, name))
                    if m:
                        versions.add((int(m[1]), int(m[2])))
                    a += anext
                at += nxt
    return needed, versions


def test_the_module_needs_no_system_openssl():
    needed, _ = needed_and_glibc(MODULE)
    assert needed, "no DT_NEEDED entries read"
    assert not [n for n in needed if re.match(r"lib(ssl|crypto)\b", n)], needed
    # Only what every manylinux system has.
    allowed = {"libc.so.6", "libm.so.6", "libgcc_s.so.1", "libpthread.so.0", "libdl.so.2", "librt.so.1", "ld-linux-x86-64.so.2", "ld-linux-aarch64.so.1"}
    assert set(needed) <= allowed, needed
    # OpenSSL is inside the module: its version string is there.
    with open(MODULE, "rb") as f:
        assert re.search(rb"OpenSSL 3\.\d+\.\d+", f.read())


def test_ldd_finds_no_libssl_or_libcrypto():
    if shutil.which("ldd") is None:
        pytest.skip("no ldd on this system")
    out = subprocess.run(["ldd", MODULE], capture_output=True, text=True, check=True).stdout
    assert "libc.so" in out, out
    assert not re.search(r"lib(ssl|crypto)\.so", out), out
    assert "not found" not in out, out


def test_the_wheel_is_abi3_and_manylinux():
    dist = importlib.metadata.distribution("hartkit")
    tags = [line.split(":", 1)[1].strip() for line in dist.read_text("WHEEL").splitlines() if line.startswith("Tag:")]
    assert tags, dist.read_text("WHEEL")
    glibc = []
    for tag in tags:
        m = re.fullmatch(r"cp39-abi3-manylinux_(\d+)_(\d+)_(x86_64|aarch64)", tag)
        assert m, f"{tag}: not a cp39-abi3-manylinux_X_Y tag"
        glibc.append((int(m[1]), int(m[2])))
    assert MODULE.endswith(".abi3.so")
    # The tag is true to the module: no glibc symbol newer than the tag says.
    _, versions = needed_and_glibc(MODULE)
    assert versions and max(versions) <= min(glibc), f"needs GLIBC {max(versions)}, tagged {tags}"


@pytest.mark.parametrize("scheme", ["tls", "dtls"])
def test_secure_hart_ip_with_the_wheels_openssl(secure_hart_ip_server, scheme):
    target = f"{scheme}://127.0.0.1:{secure_hart_ip_server}"

    async def main(psk):
        async with hartkit.connect(target, psk=psk) as loop:
            dev = await loop.device(poll=1)
            return (await dev.read_pv()).pv_units_symbol

    assert asyncio.run(main(PSK)) == "kPa"
    if scheme == "tls":  # a DTLS server drops a bad handshake silently: 10 s to time out
        identity, key = PSK.split(":")
        with pytest.raises(hartkit.TargetError) as e:
            asyncio.run(main(f"{identity}:{key[:-2]}00"))
        assert "refused the TLS handshake" in str(e.value)
