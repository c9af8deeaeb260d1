#!/usr/bin/env python3
"""The scaling model of docs/benchmarks.md ("Scaling model: wall-clock to the first successful Grasp
on 4, 8, 16 hosts of 16 cores"): prints its table from the assumptions stated there, each a flag
whose default is the figure the page gives (measured ones from dev-2c, assumed ones marked so).

    python3 scripts/scaling-model.py            # the table as docs/benchmarks.md shows it
    python3 scripts/scaling-model.py --help     # the assumptions

Model: H hosts of `threads_per_host` worker threads each (rank 0 on its own host). A thread runs
`tps` transitions/s and `ups` updates/s when compute-bound; worker ranks exchange every K updates,
so the run asks the server for `H * threads * ups / K` exchanges/s. The server manages at most
min(bandwidth / bytes per exchange, its core's exchanges/s); above that, throughput scales down
by the ratio (the link's share fitted on namespace hosts, docs/benchmarks.md). Data needed to the first success grows with the worker count as
`1 + data_growth * log2(workers)`, from `first_success` transitions at one worker.
"""

import argparse
import math

LINKS = {"1 GbE": 125e6, "10 GbE": 1250e6}  # a link's raw rate in bytes/s
K_CHOICES = [10, 20, 50, 100, 200, 500, 1000]


def rows(a):
    one_thread_min = a.first_success / a.tps / 60
    for link, bandwidth in LINKS.items():
        limit = min(a.link_efficiency * bandwidth / a.exchange_bytes, a.server_exchanges)
        for hosts in a.hosts:
            workers = hosts * a.threads_per_host
            demand_per_k = workers * a.ups  # exchanges/s times K
            smallest = next((k for k in K_CHOICES if demand_per_k / k <= limit), K_CHOICES[-1])
            for k in dict.fromkeys([a.default_k, smallest]):
                demand = demand_per_k / k
                tps = workers * a.tps * min(1.0, limit / demand)
                data = a.first_success * (1 + math.log2(workers) * a.data_growth)
                minutes = data / tps / 60
                yield hosts, link, k, tps, tps / a.tps, minutes, one_thread_min / minutes


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hosts", type=int, nargs="+", default=[4, 8, 16])
    ap.add_argument("--threads-per-host", type=int, default=15,
                    help="worker threads per host of 16 cores (one core for the exchange and the OS)")
    ap.add_argument("--tps", type=float, default=68.6,
                    help="transitions/s per thread, Grasp at R = 5 (measured: 4.27 ms a step + 5 x 2.06 ms)")
    ap.add_argument("--ups", type=float, default=343.0, help="updates/s per thread (= 5 x tps)")
    ap.add_argument("--exchange-bytes", type=float, default=570e3,
                    help="bytes the server sends per exchange (measured)")
    ap.add_argument("--link-efficiency", type=float, default=0.73,
                    help="the share of the server link's raw rate its answers get (fitted: 16.0 "
                         "exchanges/s x 570 kB on a 100 Mbit/s namespace link; was 0.936, 117 of "
                         "125 MB/s, assumed, before issue #33)")
    ap.add_argument("--server-exchanges", type=float, default=1000.0,
                    help="exchanges/s the server's one core handles (assumed)")
    ap.add_argument("--default-k", type=int, default=10, help="--exchange-every's default")
    ap.add_argument("--data-growth", type=float, default=0.25,
                    help="extra data per doubling of workers (the paper's ~2x at 16 workers; assumed)")
    ap.add_argument("--first-success", type=float, default=300_000,
                    help="transitions to the first Grasp success with one worker (assumed)")
    a = ap.parse_args()
    print("| hosts x 16 cores | link | K (`--exchange-every`) | transitions/s | throughput vs 1 thread "
          "| first Grasp success (vs 1 thread) |")
    print("|---:|---|---:|---:|---:|---|")
    for hosts, link, k, tps, speedup, minutes, faster in rows(a):
        k_text = f"{k} (default)" if k == a.default_k and hosts == a.hosts[0] and link == "1 GbE" else str(k)
        print(f"| {hosts} | {link} | {k_text} | {tps:,.0f} | {speedup:.0f}x | {minutes:.1f} min ({faster:.0f}x) |")


if __name__ == "__main__":
    main()
