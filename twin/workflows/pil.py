"""What ``twin pil`` does: an export cross-compiled for a Cortex-M4F and run under QEMU over the
readings of a run of the twin (processor in the loop, emulated, :mod:`twin.export.pil`), beside
the same main built for the host; the memory, stack and instructions per step, and how the two
duty streams compare."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from twin.errors import TwinError
from twin.export import pil
from twin.export.generate import read_manifest
from twin.scenarios import load_scenario
from twin.workflows.export import imu_mount, record_run

PERIOD_SHARE = 0.10  # the time per step the issue allows: 10 % of the control period
FLASH_BYTES, RAM_BYTES = 64 * 1024, 8 * 1024


def records_of(rec: dict) -> np.ndarray:
    """A recorded run's readings and targets (:func:`twin.workflows.export.record_run`) as the PIL
    main's input records."""
    n = len(rec["estimate"])
    out = pil.readings(n)
    out["gyro"], out["accel"] = rec["gyro"], rec["accel"]
    out["encoder"] = rec["encoder"].astype(np.int32)
    valid = rec["valid"].astype(np.uint8)
    out["gyro_valid"], out["accel_valid"], out["encoder_valid"] = valid[:, 0], valid[:, 1], valid[:, 2]
    out["has_position"] = rec["position"] is not None
    out["position"] = rec["position"] or 0.0
    out["has_heading"] = rec["heading"] is not None
    out["heading"] = rec["heading"] or 0.0
    return out


def run_pil(directory, seconds: float = 3.0, work=None, overrides=()) -> dict:
    """Build the export in ``directory`` for the Cortex-M4F and the host, run both over the first
    ``seconds`` of its scenario's run (its controller, its estimator, its seed), and return the
    figures: ``build`` (:func:`twin.export.pil.build`), ``qemu`` (instructions per step: mean, max,
    µs at 168 MHz, share of the control period), ``compare`` (:func:`twin.export.pil.compare` of
    the QEMU and host outputs), ``steps``, ``targets`` (each figure against the issue's bound)."""
    d = Path(directory)
    doc = read_manifest(d)
    if not seconds > 0:
        raise TwinError(f"--seconds must be positive, got {seconds!r}")
    sc = load_scenario(doc["scenario"], (f"sensors.estimator={doc['estimator']}", *overrides))
    context = sc.build_context()
    model = context.model
    rec = record_run(sc, doc["controller"], seconds, context.motor, float.fromhex(doc["encoder_rad_per_count"]),
                     model.b / model.r, imu_mount(context))
    with tempfile.TemporaryDirectory(prefix="mtwip-pil-") as tmp:
        w = Path(work) if work is not None else Path(tmp)
        w.mkdir(parents=True, exist_ok=True)
        readings = pil.write_readings(w / "readings.bin", records_of(rec))
        built = pil.build(d, w / "arm")
        target = pil.run(built["image"], readings)
        host = pil.run_host(pil.build_host(d, w / "host"), readings)
    rate = float(doc["control_rate_hz"])
    info = target.info
    share = info["us_max"] * 1e-6 * rate
    return {"export": str(d), "precision": doc["precision"], "arithmetic": doc.get("arithmetic", "exact"),
            "controller": doc["controller"],
            "estimator": doc["estimator"], "scenario": doc["scenario"], "steps": int(len(target.outputs)),
            "build": {k: v for k, v in built.items() if k != "image"}, "qemu": {**info, "period_share": share},
            "compare": pil.compare(target.outputs, host),
            "targets": {"flash": (built["library_flash"], FLASH_BYTES), "ram": (built["ram_bytes"], RAM_BYTES),
                        "period_share": (share, PERIOD_SHARE)}}


__all__ = ["FLASH_BYTES", "PERIOD_SHARE", "RAM_BYTES", "records_of", "run_pil"]
