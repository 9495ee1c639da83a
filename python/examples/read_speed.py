"""Times taxel.read_recording on a file: `python read_speed.py RECORDING [RUNS]`.

Prints the median and every run's wall time (time.perf_counter), and the records per stream.
docs/python.md quotes it on the 10-minute recording of the results section.
"""

import statistics
import sys
import time

import taxel


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: read_speed.py RECORDING [RUNS]")
    path = sys.argv[1]
    runs = int(sys.argv[2]) if len(sys.argv) == 3 else 5
    times = []
    rec = None
    for _ in range(runs):
        rec = None
        t0 = time.perf_counter()
        rec = taxel.read_recording(path)
        times.append(time.perf_counter() - t0)
    print(
        f"{path}: median {statistics.median(times):.3f} s over {runs} runs "
        f"({' '.join(f'{t:.3f}' for t in times)}); {rec!r}"
    )


if __name__ == "__main__":
    main()
