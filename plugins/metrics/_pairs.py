"""What the perceptual pair metrics share (`visphy_plugins.metrics.ms_ssim`, `.fsim_vsi`,
`.lpips_dists`, all family ``perceptual``, kind ``pairs``): the chunk of pairs they work on at
once, per-frame views of a batch, and how many pairs the scorer asks them for (the reasoning
behind each module's ``max_pairs`` defaults).

Pairs. The scorer computes each distinct pair of a scene once for the three pairings; with
``max_pairs`` m per pairing a 17-frame scene has about 7 (m 4), 12 (m 8) or 17 (every pair)
distinct pairs at offset 0, 10 / 18 / 32 when the aligned offset is not 0, and a 75-frame scene
7–8 / 12–20 / 75–148. The frames are fewer than twice the pairs: on the benchmark's 2D scenes
(aligned offset 2) 11 pairs use 17 distinct frames (m 4) and 20 pairs 30 (m 8); on its 3D
scenes (offset 0) each frame is used once. Defaults: m = 8
(`visphy_plugins.metrics.ms_ssim.MS_SSIM_MAX_PAIRS`, `.fsim_vsi.PIQ_MAX_PAIRS`,
`.lpips_dists.LPIPS_MAX_PAIRS`, `.lpips_dists.DISTS_MAX_PAIRS`) keeps the paper pairing of a 2D
scene whole (every 3rd of 17 frames: 6 pairs) while bounding 3D scenes; ST-LPIPS, the costliest
offline metric, runs on m = 4 (`.lpips_dists.STLPIPS_MAX_PAIRS`, at a working size of 256²: see
that module). The sampled pairs are evenly spaced in time, first and last included;
``metrics.max_pairs.<name>`` overrides (0 or null: every pair), and the value is recorded in
the identity.

Per-frame work. The scorer asks for a scene's pairs one pairing at a time (unaligned, aligned,
paper), and the same reference and generated frames come back in each (and held frames within
one). What a metric computes of one frame alone is computed once per distinct frame and kept in
the per-frame cache (`visphy_plugins.metrics._torch.per_frame`); per pair only the comparison
runs. `split_frames` hands each frame its share of a batch's results.

Threads. With two torch threads the wall time is at best about half the CPU time on idle cores,
and much worse than one thread where other processes keep the cores busy
(`_torch.default_threads`, ``$VISPHY_TORCH_THREADS``).
"""

from __future__ import annotations

#: Pairs per chunk (per forward pass, per batch of per-frame features): bounded memory on
#: 75-frame 512² clips.
CHUNK = 4


def split_frames(*batches) -> list[tuple]:
    """Per frame, a tuple of its slice (a batch of one) of each batch tensor: views, not copies
    (fresh memory costs page faults; a batch's storage is freed once all its frames are)."""
    return [tuple(b[i:i + 1] for b in batches) for i in range(len(batches[0]))]
