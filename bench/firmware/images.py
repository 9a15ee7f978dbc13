"""Where the firmware engine's ELF comes from: shipped for the packaged artifacts, built (and cached) for any other.

The three packaged artifacts (`bench/data/default_model*.json`) ship their ELF in `bench/data/firmware/` (same
stem, `.elf`), so `bench run --engine firmware` needs no compiler for them; tests/bench/firmware/test_packaged.py
rebuilds them and compares byte for byte (the compiler is pinned in pyproject for that). Regenerate them after a
change of the generator, the start-up code, the linker script or the flags with

    python -m bench.firmware.images

Any other artifact is built with the compiler (the `ziglang` dependency) into a cache directory the caller names
(under its output or temporary directory), under a key over everything the ELF is made of (the generated C, the
start-up code, the linker script, the flags and the toolchain's version), so a cached ELF is never stale.
"""

from __future__ import annotations

import hashlib
import sys
from importlib.resources import files
from pathlib import Path

from bench.errors import BenchError
from bench.fileio import write_bytes_atomically
from bench.firmware import toolchain
from bench.firmware.codegen import generate
from bench.firmware.literals import FirmwareGenerationError
from bench.progress import StepBar
from target_sim.artifact import ArtifactError, ModelArtifact, load_artifact
from target_sim.kinds import MODEL_KINDS

PACKAGED_KINDS = MODEL_KINDS.names()   # one packaged artifact per kind


def packaged_elf_path(kind: str) -> Path:
    """The shipped ELF of the packaged artifact of `kind` (bench/data/firmware/<artifact stem>.elf)."""
    from bench.model.default import default_artifact_path

    return Path(str(files("bench") / "data" / "firmware" / f"{default_artifact_path(kind).stem}.elf"))


def packaged_elf(artifact: ModelArtifact) -> Path | None:
    """The shipped ELF when `artifact` is one of the packaged artifacts (same sha256), else None."""
    from bench.model.default import default_artifact_path

    for kind in PACKAGED_KINDS:
        if artifact.kind != kind:
            continue
        try:
            packaged = load_artifact(default_artifact_path(kind))
        except ArtifactError:
            return None
        path = packaged_elf_path(kind)
        if packaged.sha256 == artifact.sha256 and path.is_file():
            return path
    return None


def _cache_key(artifact: ModelArtifact, sources: dict[str, str]) -> str:
    digest = hashlib.sha256(artifact.sha256.encode())
    for name in sorted(sources):
        digest.update(name.encode() + b"\0" + sources[name].encode() + b"\0")
    digest.update(repr((toolchain.TARGET_FLAGS, toolchain.CODE_FLAGS, toolchain.LINK_FLAGS)).encode())
    return digest.hexdigest()[:16]


def firmware_for(artifact: ModelArtifact, cache_dir: Path, *, quiet: bool = True, isr: bool = False) -> Path:
    """The ELF of `artifact`'s model: the shipped one, else `cache_dir`/<kind>-<key>.elf, built if not there yet;
    with `isr` the timing image with the current loop's interrupt (never shipped: always built, then cached).

    BenchError (one sentence) when the generator cannot express the artifact or the compiler is missing or fails."""
    shipped = None if isr else packaged_elf(artifact)
    if shipped is not None:
        return shipped
    try:
        generated = generate(artifact)
    except FirmwareGenerationError as exc:
        raise BenchError(f"the firmware engine cannot run this artifact: {exc}") from None
    sources = toolchain.firmware_sources(generated, isr=isr)
    try:
        version = toolchain.toolchain_version()
    except toolchain.ToolchainError as exc:
        raise BenchError(f"the artifact's firmware is not packaged and must be built, but {exc}") from None
    label = f"{artifact.kind}-isr" if isr else artifact.kind
    path = cache_dir / f"{label}-{_cache_key(artifact, {**sources, 'toolchain': version})}.elf"
    if path.is_file():
        damage = cached_image_problem(path, isr)
        if damage is None:
            return path
        # the key names the sources and the compiler, so another image there is damage (a truncated write of an
        # older bench, a disk error, a user's edit): rebuilt in its place, and said
        print(f"bench: the cached firmware {path} {damage}; building it again", file=sys.stderr)
    elif not quiet:
        print(f"bench: compiling the {artifact.kind} model's firmware into {path} (once)", file=sys.stderr)
    bar = StepBar(f"firmware {label}", quiet)
    try:
        result = toolchain.build_firmware(generated, isr=isr, on_step=bar)
    except toolchain.ToolchainError as exc:
        raise BenchError(f"the artifact's firmware is not packaged and must be built, but {exc}") from None
    finally:
        bar.close()
    try:
        write_bytes_atomically(path, result.elf)
    except OSError as exc:
        raise BenchError(f"cannot write the firmware cache {path} ({exc.strerror or exc}); choose another output "
                         "directory") from None
    return path


# what every image needs, and the timing image's interrupt handler (`target_sim.firmware.motor_control.HANDLER`)
IMAGE_FUNCTIONS = ("fw_step", "node_on_frame")


def cached_image_problem(path: Path, isr: bool) -> str | None:
    """Why the cached ELF at `path` cannot be used (one clause), or None."""
    from target_sim.firmware import FirmwareError, read_elf
    from target_sim.firmware.motor_control import HANDLER

    try:
        image = read_elf(path)
    except FirmwareError as exc:
        return f"is not a usable image ({exc})"
    missing = [name for name in (*IMAGE_FUNCTIONS, *((HANDLER,) if isr else ())) if name not in image.symbols]
    return f"lacks {', '.join(missing)}" if missing else None


def write_packaged(quiet: bool = False) -> list[Path]:
    """Rebuild the shipped ELFs of the packaged artifacts (needs the compiler); a bar per image on a terminal."""
    from bench.model.default import default_artifact_path

    written = []
    for number, kind in enumerate(PACKAGED_KINDS, start=1):
        bar = StepBar(f"firmware {number}/{len(PACKAGED_KINDS)} {kind}", quiet)
        try:
            build = toolchain.build_firmware(generate(load_artifact(default_artifact_path(kind))), on_step=bar)
        finally:
            bar.close()
        path = packaged_elf_path(kind)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomically(path, build.elf)
        written.append(path)
    return written


if __name__ == "__main__":
    for written_path in write_packaged():
        print(f"wrote {written_path}")
