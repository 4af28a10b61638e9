"""Processor in the loop, emulated: an export directory cross-compiled for a Cortex-M4F and run
under QEMU, step by step on recorded or synthetic readings, its outputs and its instructions per
step measured; the same main built for the host to compare the duty stream against.

:func:`build` cross-compiles the export's library (every ``*.c`` of the directory but those
under ``test/``) and the PIL main (``twin/export/c/pil/``) with ``arm-none-eabi-gcc`` for a
Cortex-M4F (``-mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16 -O2 -ffp-contract=off
-std=c99 -Wall -Wextra -Werror``), links it with newlib (``nano.specs``, its libm) and the
main's own semihosting calls, and reports the library's flash and RAM, the whole image's, the
size of ``mtwip_state_t`` and the worst stack of ``mtwip_step``'s call tree.
:func:`run` runs the image under ``qemu-system-arm``; :func:`build_host` and :func:`run_host`
build and run the same main with the host's gcc; :func:`compare` tells whether two output
streams are the same bits.

The board: QEMU's ``netduinoplus2``, an STM32F405 (Cortex-M4 with the single-precision FPU,
1 MB of flash at 0x08000000, 128 kB of SRAM at 0x20000000, SYSCLK 168 MHz), the class of part
the firmware is written for: the image is laid out as on the real chip, and SysTick runs at the
168 MHz processor clock (``mps2-an386``, the other Cortex-M4F model, has 4 MB of RAM but a
25 MHz clock: a 6.7 times coarser tick; both models have the FPU).

Instructions per step. QEMU has no cycle model, its DWT cycle counter reads 0 and no TCG
plugin is installed, so QEMU runs with ``-icount shift=4``: every guest instruction advances
the virtual clock by exactly 2**4 ns, and SysTick (a 24-bit down-counter clocked at 168 MHz of
*virtual* time) read before and after a call gives the instructions it ran: ticks × (1e9 /
168e6) / 16, within 0.37 of an instruction, so rounding gives the exact count (the instruction
reading SysTick sees the time at its start). The main times each ``mtwip_step`` and an empty
function through the same wrapper, and subtracts the wrapper's instructions; every run
checks the method on a loop of exactly 2n + 3 instructions for n = 1, 10, 1000, 100000 and
fails if one count is off by a single instruction. Checked once apart, on the steps of
tests/test_pil.py's stand-in export, against QEMU's own trace of every instruction executed
(``-singlestep -d exec,nochain``): the same counts, to the instruction, whatever the host's
load (the clock is virtual). A step of more than 6.2 million
instructions would wrap SysTick (a 37 ms step at 168 MHz). What is counted is *instructions*
(each Thumb instruction one, IT-skipped ones too, an LDM, a VDIV or a VSQRT one): the time
at 168 MHz is an estimate assuming one cycle per instruction, a lower bound in practice (the
M4 takes 2 cycles for a lone load, 1 + N for LDM/STM, 14 for VDIV/VSQRT, 1-3 for a taken branch,
and the flash wait states at 168 MHz that the ART accelerator mostly hides).

The stack. The worst chain of frames from ``mtwip_step`` down: the call graph is read off the
linked image's disassembly (``bl``, ``blx`` and tail-call branches), which, unlike gcc's
``-fcallgraph-info``, sees libgcc's helper calls (``__aeabi_*``) and into newlib; each library
function's frame is its ``.su`` figure (``-fstack-usage``), newlib's and libgcc's are read off
their prologues (``push``, ``vpush``, ``sub sp``). Interrupts' stacking is not included. Each
run also measures the stack the steps used, by painting it: a cross-check (newlib's worst paths,
such as ``sinf``'s reduction of huge arguments, are seldom taken).

The readings file (the input), little-endian:

* a 40-byte header: ``b"MTWIPIN1"``; uint32 flags (bit 0: use the scales below instead of
  ``mtwip_default_config``'s); uint32 80 (the record size); float64 gyro_scale, accel_scale,
  encoder_rad_per_count;
* one 80-byte record per step (:data:`INPUT_DTYPE`): float64 gyro[3] (offset 0), accel[3]
  (24); int32 encoder[2] (48); uint8 gyro_valid (56), accel_valid, encoder_valid,
  has_position, has_heading (60); 3 bytes of padding; float64 position (64), heading (72).
  The main converts each float64 to ``mtwip_real`` (round to nearest), as a firmware would
  read its sensors into the structs.

The outputs file (written by the main), little-endian, R = sizeof(mtwip_real) (4 or 8):

* a 64-byte header: ``b"MTWIPOU1"``; uint32 R, the record size 13 R + 8, sizeof(mtwip_state_t),
  the number of records, the clock's rate in Hz (0 on the host), the ticks of the empty call,
  the ticks of the four calibration loops; float64 MTWIP_CONTROL_RATE_HZ (offset 48); uint32
  sizeof(mtwip_outputs_t); 4 bytes of padding;
* one record per step: R duty[2], torque[2], u, theta_off, u_alpha, estimate[6] (13 reals);
  uint8 saturated[2]; 2 bytes of padding; uint32 SysTick ticks of the step;
* a 24-byte trailer: ``b"MTWIPEND"``; uint32 the number of records, the stack bytes written
  below the main's frame by ``mtwip_init`` and by the steps (the main's timing wrapper and
  I/O calls included; measured by painting the stack), 4 bytes of padding. A file without
  its trailer is an unfinished run.

Host and target. Built with ``-O2 -ffp-contract=off -std=c99`` on both (x86-64's SSE has no
excess precision, and neither side fuses a multiply-add), +, −, ×, ÷, sqrt, fmod and the
conversions are IEEE 754 on both and give the same bits; the math library does not. On a
Cortex-M4F (no double-precision FPU) newlib builds its old fdlibm float functions
(``__OBSOLETE_MATH``, newlib's ``machine/ieeefp.h``), glibc 2.36 has its own: measured on
200 000 arguments, ``sinf``, ``cosf``, ``tanf``, ``asinf``, ``acosf``, ``atanf``, ``atan2f``,
``expf``, ``logf``, ``powf`` and ``hypotf`` differ by one unit in the last place on 0.1 % to
13 % of them (never more), ``sqrtf`` and ``fmodf`` never. An export that calls them gives a
duty stream within a few float32 ulps of the host's, not the same bits; one that does not
gives the same bits (:func:`compare`: NaNs are taken as equal whatever their payload, x86 and
Arm make different default NaNs).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from twin.errors import TwinError

BOARD = "netduinoplus2"
CLOCK_HZ = 168_000_000  # the board's SYSCLK: SysTick's rate, and the rate the time per step is quoted at
ICOUNT_SHIFT = 4  # 2**4 ns of virtual time per instruction: 2.69 SysTick ticks
CPU_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16")
C_FLAGS = ("-O2", "-ffp-contract=off", "-std=c99", "-Wall", "-Wextra", "-Werror")
TARGET_FLAGS = CPU_FLAGS + C_FLAGS + ("-fstack-usage", "-ffunction-sections", "-fdata-sections")
HOST_FLAGS = C_FLAGS + ("-DMTWIP_PIL_HOST",)
PIL_SOURCES = Path(__file__).resolve().parent / "c" / "pil"
CALIBRATION_LOOPS = (1, 10, 1000, 100_000)  # pil_loop(n): exactly 2 n + 3 instructions
DEBIAN_PACKAGES = "gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm"

IN_MAGIC, OUT_MAGIC, END_MAGIC = b"MTWIPIN1", b"MTWIPOU1", b"MTWIPEND"
IN_HEADER, OUT_HEADER, OUT_TRAILER = 40, 64, 24

#: one record of the readings file: the readings and the targets of one step
INPUT_DTYPE = np.dtype({
    "names": ["gyro", "accel", "encoder", "gyro_valid", "accel_valid", "encoder_valid", "has_position",
              "has_heading", "position", "heading"],
    "formats": [("<f8", 3), ("<f8", 3), ("<i4", 2), "u1", "u1", "u1", "u1", "u1", "<f8", "<f8"],
    "offsets": [0, 24, 48, 56, 57, 58, 59, 60, 64, 72],
    "itemsize": 80})

OUTPUT_FIELDS = ("duty", "torque", "u", "theta_off", "u_alpha", "estimate", "saturated")
_REAL_FIELDS = (("duty", 2), ("torque", 2), ("u", 1), ("theta_off", 1), ("u_alpha", 1), ("estimate", 6))


def output_dtype(precision: str = "float32") -> np.dtype:
    """The array :func:`run` and :func:`run_host` return: ``mtwip_outputs_t``'s fields, a row per step."""
    real = {"float32": "<f4", "float64": "<f8"}[precision]
    return np.dtype([(name, real, (n,)) if n > 1 else (name, real) for name, n in _REAL_FIELDS]
                    + [("saturated", "u1", (2,))])


def readings(n: int) -> np.ndarray:
    """``n`` zeroed records of :data:`INPUT_DTYPE` (no sample valid, no target) to fill in."""
    return np.zeros(int(n), INPUT_DTYPE)


def write_readings(path, records, config: dict | None = None) -> Path:
    """Write the readings file: ``records`` (an array of :data:`INPUT_DTYPE`) after the header;
    ``config`` (``gyro_scale``, ``accel_scale``, ``encoder_rad_per_count``) replaces the default
    configuration's scales, all three."""
    records = np.asarray(records)
    if records.dtype != INPUT_DTYPE:
        raise TwinError(f"the readings must be an array of pil.INPUT_DTYPE, got dtype {records.dtype}")
    scales = (1.0, 1.0, 1.0)
    if config is not None:
        try:
            scales = tuple(float(config[k]) for k in ("gyro_scale", "accel_scale", "encoder_rad_per_count"))
        except (KeyError, TypeError, ValueError):
            raise TwinError("config must give gyro_scale, accel_scale and encoder_rad_per_count as numbers") from None
    header = IN_MAGIC + np.array([int(config is not None), INPUT_DTYPE.itemsize], "<u4").tobytes() \
        + np.array(scales, "<f8").tobytes()
    path = Path(path)
    path.write_bytes(header + np.ascontiguousarray(records).tobytes())
    return path


# --- the tools ------------------------------------------------------------------------------

def _tool(name: str, packages: str = DEBIAN_PACKAGES) -> str:
    path = shutil.which(name)
    if path is None:
        raise TwinError(f"{name} not found on PATH: processor in the loop needs it "
                        f"(Debian: apt-get install {packages})")
    return path


def _first_lines(text: str, lines: int = 4) -> str:
    kept = [ln.strip() for ln in text.strip().splitlines() if ln.strip()][:lines]
    return " | ".join(kept) if kept else "(no output)"


def _call(argv, what: str, timeout: float = 120, cwd=None) -> str:
    try:
        r = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, cwd=cwd)
    except subprocess.TimeoutExpired:
        raise TwinError(f"{what}: {Path(argv[0]).name} took over {timeout:g} s; stopped") from None
    except OSError as e:
        raise TwinError(f"{what}: cannot run {argv[0]} ({e.strerror or e})") from None
    if r.returncode != 0:
        raise TwinError(f"{what} ({Path(argv[0]).name} exit {r.returncode}): {_first_lines(r.stderr or r.stdout)}")
    return r.stdout


def _library_sources(directory: Path) -> list[Path]:
    if not directory.is_dir():
        raise TwinError(f"export directory {str(directory)!r} does not exist")
    if not (directory / "mtwip.h").is_file():
        raise TwinError(f"{str(directory)!r} holds no mtwip.h: not an export directory")
    sources = sorted(p for p in directory.rglob("*.c") if "test" not in p.relative_to(directory).parts[:-1])
    if not sources:
        raise TwinError(f"{str(directory)!r} holds no .c file: nothing to build")
    return sources


def _object_name(directory: Path, source: Path) -> str:
    return "__".join(source.relative_to(directory).with_suffix("").parts)


# --- build ---------------------------------------------------------------------------------

def build(dir, out_dir) -> dict:
    """Cross-compile export ``dir`` with the PIL main into ``out_dir/pil.elf`` (objects, ``.su``
    files, the map and the disassembly in ``out_dir/target/``).

    Returns ``image`` (its path), ``board``, ``precision``; ``library_flash`` (text + data of
    the library's objects, bytes; text counts the constant tables), ``library_ram`` (data +
    bss: the library's own globals), ``library_objects`` (per object: text, data, bss);
    ``image_flash``, ``image_ram`` (the linked image, newlib's libm and the main included; the
    stack apart); ``state_bytes`` (``sizeof(mtwip_state_t)``: the caller's RAM); ``stack_bytes``
    (the worst stack of ``mtwip_step``'s call tree), ``stack_path`` (that chain, each function
    with its frame and where the frame was read: the compiler's ``.su`` for the library's
    functions, the image's prologues for newlib's and libgcc's), ``stack_exact`` (False when
    the tree has an indirect call, recursion or a dynamic frame: then the figure is a lower
    bound, see ``stack_notes``); ``ram_bytes`` = library_ram + state_bytes + stack_bytes.
    """
    directory = Path(dir).resolve()
    sources = _library_sources(directory)
    out = Path(out_dir).resolve()
    work = out / "target"
    work.mkdir(parents=True, exist_ok=True)
    cc = _tool("arm-none-eabi-gcc")
    size_tool, nm, objdump = (_tool(f"arm-none-eabi-{t}", "gcc-arm-none-eabi binutils-arm-none-eabi")
                              for t in ("size", "nm", "objdump"))
    libc = _call([cc, *CPU_FLAGS, "-print-file-name=libc_nano.a"], "probing newlib").strip()
    if not os.path.isabs(libc):
        raise TwinError("newlib for arm-none-eabi is missing (no libc_nano.a): apt-get install libnewlib-arm-none-eabi")
    for stale in list(work.glob("*.o")) + list(work.glob("*.su")):
        stale.unlink()

    def compile_one(item):
        source, obj, is_library = item
        what = (f"export {str(directory)!r} does not compile for the Cortex-M4F" if is_library
                else f"the PIL main does not compile with export {str(directory)!r}")
        _call([cc, *TARGET_FLAGS, "-I", str(directory), "-I", str(PIL_SOURCES), "-c", str(source), "-o", str(obj)],
              what)

    jobs = [(s, work / f"{_object_name(directory, s)}.o", True) for s in sources]
    lib_objects = [obj for _, obj, _ in jobs]
    jobs += [(PIL_SOURCES / f"{n}.c", work / f"_pil_{n}.o", False) for n in ("pil_main", "pil_target")]
    with ThreadPoolExecutor(max_workers=max(1, min(len(jobs), os.cpu_count() or 1))) as pool:
        list(pool.map(compile_one, jobs))  # the first error raises, in the sources' order

    image = out / "pil.elf"
    _call([cc, *CPU_FLAGS, "--specs=nano.specs", "-nostartfiles", "-T", str(PIL_SOURCES / "pil.ld"),
           "-Wl,--gc-sections", f"-Wl,-Map={work / 'pil.map'}", *(str(j[1]) for j in jobs),
           "-Wl,--start-group", "-lm", "-lc", "-lgcc", "-Wl,--end-group", "-o", str(image)],
          f"export {str(directory)!r} does not link for the Cortex-M4F")

    sizes = _sizes(_call([size_tool, "-B", *map(str, lib_objects), str(image)], "reading the sizes"))
    objects = {Path(p).stem: s for p, s in sizes.items() if p != str(image)}
    lib = np.sum([list(s) for s in objects.values()], axis=0)
    img = sizes[str(image)]
    symbols = _symbol_sizes(_call([nm, "-S", "--defined-only", str(work / "_pil_pil_main.o")], "reading the sizes"))
    real_size = symbols.get("pil_real")
    if real_size not in (4, 8):
        raise TwinError(f"mtwip_real is {real_size} bytes in export {str(directory)!r}: "
                        f"float (4) or double (8) expected")
    disassembly = _call([objdump, "-d", "--no-show-raw-insn", str(image)], "disassembling the image")
    (work / "pil.dis").write_text(disassembly)
    stack = stack_tree(disassembly, _su_frames(work, lib_objects), "mtwip_step")
    state_bytes = symbols["pil_state"]
    return {
        "image": str(image), "board": BOARD, "precision": "float32" if real_size == 4 else "float64",
        "library_flash": int(lib[0] + lib[1]), "library_ram": int(lib[1] + lib[2]),
        "library_objects": {k: {"text": t, "data": d, "bss": b} for k, (t, d, b) in objects.items()},
        "image_flash": img[0] + img[1], "image_ram": img[1] + img[2],
        "state_bytes": state_bytes, "stack_bytes": stack["bytes"], "stack_path": stack["path"],
        "stack_exact": stack["exact"], "stack_notes": stack["notes"],
        "ram_bytes": int(lib[1] + lib[2]) + state_bytes + stack["bytes"],
    }


def _sizes(text: str) -> dict[str, tuple[int, int, int]]:
    """``size -B``'s rows: file → (text, data, bss)."""
    rows = {}
    for line in text.splitlines()[1:]:
        parts = line.split(None, 5)
        if len(parts) == 6:
            rows[parts[5]] = (int(parts[0]), int(parts[1]), int(parts[2]))
    return rows


def _symbol_sizes(text: str) -> dict[str, int]:
    rows = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 4:
            rows[parts[3]] = int(parts[1], 16)
    return rows


def _su_frames(work: Path, objects) -> dict[str, tuple[int, str]]:
    """The library's functions' frames from gcc's ``.su`` files: name → (bytes, qualifier);
    a name defined in two files (two static functions) keeps the larger."""
    frames: dict[str, tuple[int, str]] = {}
    for obj in objects:
        su = obj.with_suffix(".su")
        if not su.is_file():
            continue
        for line in su.read_text().splitlines():
            parts = line.rsplit("\t", 2)
            if len(parts) != 3:
                continue
            name = parts[0].rsplit(":", 1)[-1]
            size, qualifier = int(parts[1]), parts[2].strip()
            if name not in frames or frames[name][0] < size:
                frames[name] = (size, qualifier)
    return frames


# --- the stack: the call tree from the image's disassembly -----------------------------------

_HEADER = re.compile(r"^([0-9a-f]+) <([^>]+)>:$")
_INSN = re.compile(r"^\s*([0-9a-f]+):\s+(\S+)\s*(.*)$")
_TARGET = re.compile(r"\b([0-9a-f]+) <([^>+]+)(\+0x[0-9a-f]+)?>")
_REGLIST = re.compile(r"\{([^}]*)\}")
_IMM = re.compile(r"#(-?\d+)")


def _reglist_bytes(operands: str) -> int:
    m = _REGLIST.search(operands)
    if not m:
        return 0
    total = 0
    for item in m.group(1).split(","):
        item = item.strip()
        width = 8 if item.startswith("d") else 4
        if "-" in item:
            a, b = item.split("-")
            total += width * (int(b.strip()[1:]) - int(a.strip()[1:]) + 1)
        elif item:
            total += width
    return total


def _frame_growth(mnemonic: str, operands: str) -> tuple[int, bool]:
    """(bytes the instruction moves sp down by, whether it moves it by a register's value)."""
    m = mnemonic.split(".")[0]
    ops = operands.split(";")[0].split("@")[0].strip()
    if m in ("push", "vpush") or (m in ("stmdb", "stmfd", "vstmdb") and ops.startswith("sp!")):
        return _reglist_bytes(ops), False
    if m in ("sub", "subw", "subs") and re.match(r"sp,\s*(sp,\s*)?", ops):
        imm = _IMM.search(ops)
        return (int(imm.group(1)), False) if imm else (0, True)
    if m in ("str", "strd", "vstr") and re.search(r"\[sp,\s*#-\d+\]!", ops):
        return -int(re.search(r"\[sp,\s*#(-\d+)\]!", ops).group(1)), False
    if m == "mov" and ops.startswith("sp,"):
        return 0, True
    return 0, False


def stack_tree(disassembly: str, su_frames: dict, root: str = "mtwip_step") -> dict:
    """The worst stack of ``root``'s call tree in an image's disassembly (``objdump -d
    --no-show-raw-insn``): the largest sum of frames along a chain of calls (``bl``, ``blx``, and
    tail calls: a branch to another function's start). A function's frame is its ``.su`` figure
    when ``su_frames`` (name → (bytes, qualifier)) has it, else the sum of every ``push``,
    ``vpush`` and ``sub sp`` in its body (an upper bound when shrink-wrapping pushes on two
    paths). Returns ``bytes``, ``path`` (``[(name, frame, "su" or "binary")]``), ``exact`` and
    ``notes`` (indirect calls, recursion, dynamic frames: the figure is then a lower bound)."""
    functions: dict[int, dict] = {}
    current = None
    for line in disassembly.splitlines():
        h = _HEADER.match(line)
        if h:
            current = functions.setdefault(int(h.group(1), 16), {"name": h.group(2), "calls": set(), "growth": 0,
                                                                   "dynamic": False, "indirect": False})
            continue
        i = _INSN.match(line)
        if current is None or not i:
            continue
        mnemonic, operands = i.group(2), i.group(3)
        if mnemonic.startswith("."):  # .word, .short: a literal pool
            continue
        grow, dynamic = _frame_growth(mnemonic, operands)
        current["growth"] += grow
        current["dynamic"] |= dynamic
        base = mnemonic.split(".")[0]
        t = _TARGET.search(operands)
        if base in ("bl", "blx") or (base.startswith("b") and base not in ("bic", "bics", "bfi", "bfc", "bkpt", "bx")):
            if t and (base in ("bl", "blx") or (t.group(3) is None and t.group(2) != current["name"])):
                current["calls"].add(int(t.group(1), 16))
            elif base == "blx" and not t:
                current["indirect"] = True
        elif base == "bx" and operands.split()[0] != "lr":
            current["indirect"] = True
    by_name = {f["name"]: a for a, f in functions.items()}
    if root not in by_name:
        raise TwinError(f"{root} is not in the image: the export does not define it")
    notes: list[str] = []

    def frame(f) -> tuple[int, str]:
        if f["name"] in su_frames:
            size, qualifier = su_frames[f["name"]]
            if qualifier != "static":
                notes.append(f"{f['name']}: a {qualifier} frame ({size} bytes at least)")
            return size, "su"
        if f["dynamic"]:
            notes.append(f"{f['name']}: moves sp by a register's value (a dynamic frame)")
        return f["growth"], "binary"

    best: dict[int, tuple[int, list]] = {}
    on_path: set[int] = set()

    def worst(address: int) -> tuple[int, list]:
        if address in best:
            return best[address]
        f = functions.get(address)
        if f is None:
            notes.append(f"a call to 0x{address:x}, outside every function")
            return 0, []
        if f["indirect"]:
            notes.append(f"{f['name']}: an indirect call")
        size, source = frame(f)
        on_path.add(address)
        deepest: tuple[int, list] = (0, [])
        for callee in sorted(f["calls"]):
            if callee in on_path:
                notes.append(f"{f['name']}: recursion through {functions[callee]['name']}")
                continue
            deepest = max(deepest, worst(callee), key=lambda c: c[0])
        on_path.discard(address)
        best[address] = (size + deepest[0], [(f["name"], size, source)] + deepest[1])
        return best[address]

    total, path = worst(by_name[root])
    notes = sorted(set(notes))
    return {"bytes": total, "path": path, "exact": not notes, "notes": notes}


# --- run -----------------------------------------------------------------------------------

class PilRun(tuple):
    """What :func:`run` returns: unpacks as ``(outputs, instructions)``; ``.info`` has the rest."""

    def __new__(cls, outputs, instructions, info):
        self = super().__new__(cls, (outputs, instructions))
        self.info = info
        return self

    @property
    def outputs(self) -> np.ndarray:
        return self[0]

    @property
    def instructions(self) -> np.ndarray:
        return self[1]


def run(image, readings_file, *, timeout: float = 60.0) -> PilRun:
    """Run a :func:`build` image under QEMU on a readings file (:func:`write_readings`).

    Returns ``(outputs, instructions)``: an array of :func:`output_dtype` (a row per record)
    and the instructions of each ``mtwip_step`` (int64); ``.info`` of the result holds
    ``instructions_mean``, ``instructions_max``, ``us_mean``, ``us_max`` (at 168 MHz, one
    instruction a cycle: an estimate), ``budget_max`` (the worst step's share of a control
    period), ``control_rate_hz``, ``state_bytes``, ``stack_init_bytes``, ``stack_step_bytes``
    (measured), ``calibration`` (loop n → instructions counted, each 2n + 3) and the QEMU
    command line."""
    qemu = _tool("qemu-system-arm", "qemu-system-arm")
    image = Path(image).resolve()
    readings_file = Path(readings_file).resolve()
    if not image.is_file():
        raise TwinError(f"no PIL image at {str(image)!r}: build it first (pil.build)")
    if not readings_file.is_file():
        raise TwinError(f"no readings file at {str(readings_file)!r}")
    argv = [qemu, "-M", BOARD, "-nographic", "-monitor", "none", "-serial", "none",
            "-semihosting-config", "enable=on,target=native",
            "-icount", f"shift={ICOUNT_SHIFT},align=off,sleep=off", "-kernel", str(image)]
    with tempfile.TemporaryDirectory(prefix="twin-pil-") as tmp:
        try:
            os.symlink(readings_file, Path(tmp) / "pil_in.bin")
        except OSError:
            shutil.copyfile(readings_file, Path(tmp) / "pil_in.bin")
        try:
            r = subprocess.run(argv, cwd=tmp, capture_output=True, timeout=timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            raise TwinError(f"the PIL image did not finish under QEMU in {timeout:g} s (an endless loop, or too many "
                            f"records for the timeout); stopped") from None
        except OSError as e:
            raise TwinError(f"cannot run {qemu} ({e.strerror or e})") from None
        if r.returncode != 0:
            said = _first_lines(r.stderr.decode(errors="replace") + r.stdout.decode(errors="replace"), 2)
            raise TwinError(f"the PIL image failed under QEMU (exit {r.returncode}): {said}")
        data = (Path(tmp) / "pil_out.bin").read_bytes() if (Path(tmp) / "pil_out.bin").is_file() else b""
    outputs, ticks, info = parse_outputs(data)
    if info["clock_hz"] != CLOCK_HZ:
        raise TwinError(f"the PIL image says its clock is {info['clock_hz']} Hz, {CLOCK_HZ} expected: "
                        f"not a pil.build image")
    instructions = _instructions(ticks, info["empty_ticks"])
    counted = dict(zip(CALIBRATION_LOOPS, (int(v) for v in _instructions(np.array(info["loop_ticks"]),
                                                                         info["empty_ticks"]))))
    wrong = {n: c for n, c in counted.items() if c != 2 * n + 3}
    if wrong:
        raise TwinError(f"instruction counting failed its check under this QEMU: loops of 2n + 3 instructions counted "
                        f"{wrong} for n = {list(wrong)}")
    period_instructions = CLOCK_HZ / info["control_rate_hz"] if info["control_rate_hz"] > 0 else float("nan")
    n_max = int(instructions.max()) if len(instructions) else 0
    info.update({
        "board": BOARD, "icount_shift": ICOUNT_SHIFT, "calibration": counted, "qemu": argv,
        "instructions_mean": float(instructions.mean()) if len(instructions) else 0.0, "instructions_max": n_max,
        "us_mean": float(instructions.mean()) * 1e6 / CLOCK_HZ if len(instructions) else 0.0,
        "us_max": n_max * 1e6 / CLOCK_HZ, "budget_max": n_max / period_instructions,
    })
    return PilRun(outputs, instructions, info)


def _instructions(ticks, empty_ticks: int) -> np.ndarray:
    """SysTick ticks of a timed call → the instructions of the call's callee: each reading in
    instructions (2**shift ns each) is within 0.37 of an integer, so each is rounded apart; the
    empty callee's one instruction (bx lr) is the wrapper's overhead taken off."""
    per_tick = 1e9 / CLOCK_HZ / 2 ** ICOUNT_SHIFT
    empty = round(empty_ticks * per_tick)
    return np.rint(np.asarray(ticks, dtype=np.float64) * per_tick).astype(np.int64) - empty + 1


def parse_outputs(data: bytes) -> tuple[np.ndarray, np.ndarray, dict]:
    """An outputs file's bytes → (outputs, ticks per step, the header's and trailer's figures)."""
    if len(data) < OUT_HEADER + OUT_TRAILER or data[:8] != OUT_MAGIC:
        raise TwinError("the PIL main wrote no outputs file, or one without its header: it stopped early")
    h = np.frombuffer(data, "<u4", 16, 0)
    real_size, record, state_bytes, n, clock_hz, empty_ticks = (int(v) for v in h[2:8])
    if real_size not in (4, 8) or record != 13 * real_size + 8:
        raise TwinError(f"the outputs file's header is malformed (real {real_size} bytes, record {record} bytes)")
    if len(data) != OUT_HEADER + n * record + OUT_TRAILER or data[-OUT_TRAILER:][:8] != END_MAGIC:
        raise TwinError(f"the outputs file is cut short: {len(data)} bytes for {n} records (the run stopped early)")
    trailer = np.frombuffer(data, "<u4", 5, len(data) - OUT_TRAILER)
    real = "<f4" if real_size == 4 else "<f8"
    body = np.frombuffer(data, np.uint8, n * record, OUT_HEADER).reshape(n, record)
    reals = body[:, :13 * real_size].copy().view(real).reshape(n, 13)
    outputs = np.zeros(n, output_dtype("float32" if real_size == 4 else "float64"))
    column = 0
    for name, width in _REAL_FIELDS:
        outputs[name] = reals[:, column] if width == 1 else reals[:, column:column + width]
        column += width
    outputs["saturated"] = body[:, 13 * real_size:13 * real_size + 2]
    ticks = body[:, 13 * real_size + 4:].copy().view("<u4").reshape(n).astype(np.int64)
    info = {"precision": "float32" if real_size == 4 else "float64", "state_bytes": state_bytes, "records": n,
            "clock_hz": clock_hz, "empty_ticks": empty_ticks, "loop_ticks": [int(v) for v in h[8:12]],
            "control_rate_hz": float(np.frombuffer(data, "<f8", 1, 48)[0]), "outputs_bytes": int(h[14]),
            "stack_init_bytes": int(trailer[3]), "stack_step_bytes": int(trailer[4])}
    return outputs, ticks, info


# --- the host ------------------------------------------------------------------------------

def build_host(dir, out_dir, cc: str = "gcc") -> Path:
    """Build the PIL main and export ``dir``'s library for the host with ``cc`` (gcc by default:
    ``-O2 -ffp-contract=off -std=c99``, glibc's libm) into ``out_dir/pil-host``; returns its path."""
    directory = Path(dir).resolve()
    sources = _library_sources(directory)
    compiler = _tool(cc, "gcc")
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    exe = out / "pil-host"
    _call([compiler, *HOST_FLAGS, "-I", str(directory), "-I", str(PIL_SOURCES), *map(str, sources),
           str(PIL_SOURCES / "pil_main.c"), str(PIL_SOURCES / "pil_host.c"), "-lm", "-o", str(exe)],
          f"export {str(directory)!r} does not compile for the host")
    return exe


def run_host(executable, readings_file, *, timeout: float = 60.0) -> np.ndarray:
    """Run a :func:`build_host` executable on a readings file; returns the outputs as :func:`run` does."""
    readings_file = Path(readings_file).resolve()
    if not readings_file.is_file():
        raise TwinError(f"no readings file at {str(readings_file)!r}")
    with tempfile.TemporaryDirectory(prefix="twin-pil-host-") as tmp:
        out = Path(tmp) / "pil_out.bin"
        try:
            r = subprocess.run([str(executable), str(readings_file), str(out)], capture_output=True, timeout=timeout,
                               stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            raise TwinError(f"the host PIL main did not finish in {timeout:g} s; stopped") from None
        except OSError as e:
            raise TwinError(f"cannot run {executable} ({e.strerror or e})") from None
        if r.returncode != 0:
            raise TwinError(f"the host PIL main failed (exit {r.returncode}): "
                            f"{_first_lines(r.stderr.decode(errors='replace'), 2)}")
        data = out.read_bytes() if out.is_file() else b""
    return parse_outputs(data)[0]


def compare(a: np.ndarray, b: np.ndarray) -> dict:
    """Two output streams field by field: ``identical`` (every value the same bits, NaNs equal
    whatever their payload), and per field that differs: the steps that differ, the largest
    absolute difference and the largest difference in units in the last place."""
    if a.dtype != b.dtype or a.shape != b.shape:
        raise TwinError(f"cannot compare outputs of {a.dtype}×{a.shape} with {b.dtype}×{b.shape}")
    fields = {}
    for name in a.dtype.names:
        x, y = a[name], b[name]
        if x.dtype.kind == "f":
            same = (x.view(f"u{x.itemsize}") == y.view(f"u{x.itemsize}")) | (np.isnan(x) & np.isnan(y))
            ints = f"i{x.itemsize}"
            ulp = np.abs(x.view(ints).astype(np.int64) - y.view(ints).astype(np.int64))
            ulp = np.where(np.sign(x) == np.sign(y), ulp, np.iinfo(np.int64).max)
        else:
            same, ulp = x == y, np.abs(x.astype(np.int64) - y.astype(np.int64))
        rows = ~same.reshape(len(x), -1).all(axis=1) if x.ndim > 1 else ~same
        if rows.any():
            with np.errstate(invalid="ignore"):
                diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
            fields[name] = {"steps": int(rows.sum()), "first_step": int(np.argmax(rows)),
                            "max_abs": float(np.nanmax(np.where(same, 0.0, diff))),
                            "max_ulp": int(np.max(np.where(same, 0, ulp)))}
    return {"identical": not fields, "fields": fields}


__all__ = ["BOARD", "CLOCK_HZ", "DEBIAN_PACKAGES", "INPUT_DTYPE", "OUTPUT_FIELDS", "PilRun", "build", "build_host",
           "compare", "output_dtype", "parse_outputs", "readings", "run", "run_host", "stack_tree", "write_readings"]
