"""A reader for the one-way tests: ``python -m tests.support.rigs.zenoh_slow_reader ENDPOINT
DELAY_S`` reads the whole skin through ``subscribe`` and takes DELAY_S over each sample (a slow
reader that holds Zenoh's receiving thread); it prints ``got N`` as it goes, until killed."""

from __future__ import annotations

import sys
import time

from canbus.master.zenoh_settings import ZenohSettings
from canbus.zenoh.reader import subscribe


def main() -> None:
    endpoint, delay = sys.argv[1], float(sys.argv[2])
    count = 0

    def slow(sample: object) -> None:
        nonlocal count
        count += 1
        print(f"got {count}", flush=True)
        time.sleep(delay)  # pacing: the slow reader holds Zenoh's thread this long

    with subscribe(settings=ZenohSettings(connect=(endpoint,)), ring=1, on_sample=slow):
        print("subscribed", flush=True)
        time.sleep(120.0)  # pacing: reads until killed


if __name__ == "__main__":
    main()
