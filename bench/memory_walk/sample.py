"""One CSV row of bench/memory_walk/run.sh: seconds since T0, the SMA's
VmRSS and VmHWM (/proc/PID/status) and a few of its metrics (the Prometheus
text on stdin; an absent metric is written empty)."""
import sys
import time

t0, pid = float(sys.argv[1]), sys.argv[2]
status = {}
with open(f"/proc/{pid}/status") as f:
    for line in f:
        key, _, value = line.partition(":")
        status[key] = value.strip()


def kib(key):
    return str(int(status[key].split()[0]) * 1024) if key in status else ""


metrics = {}
for line in sys.stdin:
    if line.startswith("#") or not line.strip():
        continue
    name, _, value = line.rpartition(" ")
    metrics[name.strip()] = value.strip()

wanted = [
    "penumbra_sma_memory_bytes",
    'penumbra_sma_memory_part_bytes{part="cache"}',
    'penumbra_sma_memory_part_bytes{part="hierarchy"}',
    'penumbra_sma_memory_part_bytes{part="clients"}',
    "penumbra_sma_samples_shaded_total",
    "penumbra_sma_prediction_hit_ratio",
    "penumbra_sma_memory_in_use_bytes",
    "penumbra_sma_samples_evicted_total",
    "penumbra_sma_samples_reshaded_after_eviction_total",
    "penumbra_sma_collected_nodes_total",
    "penumbra_sma_memory_trimmed_bytes_total",
]
row = [f"{time.time() - t0:.1f}", kib("VmRSS"), kib("VmHWM")] + [metrics.get(w, "") for w in wanted]
print(",".join(row))
