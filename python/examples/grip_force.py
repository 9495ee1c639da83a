"""A grip-force loop in Python on a live force stream, with its sample-age percentiles.

The Python twin of `taxel control`: a PI controller drives a simulated hand (50 ms first-order
grip actuator) toward a target force, holds the grip (safe state) on a flagged, stale or
missing sample, and prints once a second the rate, the force and the age of the samples when
they reached this script (time.monotonic_ns() - t_capture_ns; the same clock as the capture
stamp). Ages count from the first sample captured after the first one arrived, as in
`taxel control` (earlier ones are the start-up backlog).

    taxel demo --rate-hz 1000 &                       # or any pipeline; note its prefix
    python grip_force.py --sensor s0 --prefix rdm_ --seconds 10
"""

import argparse
import math
import time

import taxel


def percentile(sorted_values, p):
    if not sorted_values:
        return float("nan")
    return sorted_values[min(len(sorted_values) - 1, int(p / 100 * len(sorted_values)))]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensor", default="s0")
    ap.add_argument("--prefix", default=None, help="iceoryx2 prefix (default: TAXEL_PREFIX or taxel_)")
    ap.add_argument("--wake", default="event", choices=["event", "busy", "adaptive"])
    ap.add_argument("--target-n", type=float, default=4.0)
    ap.add_argument("--kp", type=float, default=0.05)
    ap.add_argument("--ki", type=float, default=0.5)
    ap.add_argument("--deadline-ms", type=float, default=5.0)
    ap.add_argument("--watchdog-ms", type=float, default=50.0)
    ap.add_argument("--seconds", type=float, default=None)
    a = ap.parse_args()

    command, position, integral = 0.0, 0.0, 0.0
    last_t = None
    first_arrival = None
    window, total = [], []
    misses = safe_entries = received = 0
    safe = True
    start = time.monotonic()
    next_report = start + 1.0
    unsafe = ("no_baseline", "curvature_stale", "saturated")
    sub = taxel.subscribe(a.sensor, prefix=a.prefix, wake=a.wake)
    try:
        while a.seconds is None or time.monotonic() - start < a.seconds:
            s = sub.next(timeout=a.watchdog_ms / 1000)
            now = time.monotonic_ns()
            if s is None:
                if not safe:
                    safe, safe_entries = True, safe_entries + 1
                    print(f"[{a.sensor}] no force sample for {a.watchdog_ms:.0f} ms: safe state")
                continue
            received += 1
            age = now - s.t_capture_ns
            if first_arrival is None:
                first_arrival = now
            stale = age > a.deadline_ms * 1e6
            if s.t_capture_ns >= first_arrival:
                window.append(age)
                total.append(age)
                misses += stale
            dt = 0.0 if last_t is None else (s.t_capture_ns - last_t) * 1e-9
            last_t = s.t_capture_ns
            flags = s.flags
            if stale or any(getattr(flags, f) for f in unsafe) or not math.isfinite(s.total_force_n):
                if not safe:
                    safe, safe_entries = True, safe_entries + 1
            else:
                safe = False
                error = a.target_n - s.total_force_n
                u = a.kp * error + integral + a.ki * error * min(dt, 0.1)
                if 0.0 <= u <= 1.0:
                    integral += a.ki * error * min(dt, 0.1)
                command = min(max(u, 0.0), 1.0)
            position += (command - position) * (1 - math.exp(-max(dt, 0.0) / 0.05))
            if time.monotonic() >= next_report:
                window.sort()
                print(f"[{a.sensor}] {len(window):5d} Hz | array {s.total_force_n:5.2f} N | "
                      f"cal v{s.cal_version} | age p50 {percentile(window, 50) / 1e3:6.1f} us "
                      f"p99 {percentile(window, 99) / 1e3:6.1f} us | misses {misses} | "
                      f"grip {position:.2f} {'SAFE' if safe else 'ok'}", flush=True)
                window.clear()
                next_report += 1.0
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
    total.sort()
    print(f"[{a.sensor}] summary: {received} samples in {time.monotonic() - start:.1f} s, "
          f"age p50 {percentile(total, 50) / 1e3:.1f} us p90 {percentile(total, 90) / 1e3:.1f} us "
          f"p99 {percentile(total, 99) / 1e3:.1f} us max {percentile(total, 100) / 1e3:.1f} us, "
          f"deadline misses {misses} (> {a.deadline_ms} ms), safe-state entries {safe_entries}")


if __name__ == "__main__":
    main()
