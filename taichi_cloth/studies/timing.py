"""Timed repeats and benchmark rows, shared by the reference-sheet and the scene benchmarks."""

import statistics
import time


def timed_rate(run_batch, units_per_batch: int, seconds: float, repeats: int) -> list[float]:
    """Rates (units per second) of ``repeats`` timed repeats, each running batches for at
    least ``seconds``; ``run_batch`` must finish its work (sync) before returning."""
    rates = []
    for _ in range(repeats):
        done, started = 0, time.perf_counter()
        while True:
            run_batch()
            done += units_per_batch
            elapsed = time.perf_counter() - started
            if elapsed >= seconds:
                break
        rates.append(done / elapsed)
    return rates


def substep_row(kind: str, integrator: str, size, particles: int, rates: list[float],
                **extra) -> dict:
    rate = statistics.median(rates)
    return {"benchmark": kind, "integrator": integrator, "size": size, "particles": particles,
            "substeps_per_second": rate, "particle_substeps_per_second": rate * particles,
            "repeats": [round(r, 3) for r in rates], **extra}
