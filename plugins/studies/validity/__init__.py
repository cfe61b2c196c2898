"""The validity studies: do the metrics measure physics? (issues 9, 21, 32)

Scores are computed through `visphy_core.api.scoring` (the scorer a run uses, called on clips
made here); the clips are drawn like the generated benchmark's ground truth
(`visphy_plugins.datasets.visphybench`). Import the submodules directly: this package imports
nothing.

* `perturbation`: one physical parameter pushed away from the truth in growing steps; does
  every metric worsen monotonically? (also `scene_of`: a `Scene` for a spec in memory)
* the validity ordering (issues 21, 32): does a score put physics above drawing, and both above
  "nothing moves"?

  * `clips`: the ground truth (`Truth`), its renderers, the clip record, the clip cache and the
    scored records (`ClipScore`, `SceneOrder`);
  * `restyles`: the (i) clips, the physics right and drawn differently (`APPEARANCES`);
  * `interventions`: the (ii) clips, the physics changed and re-simulated
    (`INTERVENTIONS`), and how far a clip's bodies depart from the truth's (`deviation`);
  * `study`: the baselines ((iii), (iv)), a scene's clips made (`make_clips`) and scored
    (`score_truth`), every scene of a study (`run_order_study`);
  * `order`: how each score orders the kinds (`summarise_order`), the headline's placement
    and its alternatives;
  * `dose`: the dose series, and whether a score is monotone in the dose;
  * `goals`: the validity goals measured, and the summary the study writes
    (`visphy_core/api/validity_summary.json`).
"""
