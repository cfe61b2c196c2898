"""Studies of the metrics: tools that score clips outside a run to ask what a metric measures.

They are plugins like the others in what they may import (``visphy_core.api``, and the other
plugins: the generated dataset draws their clips, the baselines' models make theirs), but no
run loads them: nothing registers them in the ``visphy`` entry points. The benchmarks drive
them (``benchmarks/validity_study.py``, ``benchmarks/validity_headlines.py``).

* `visphy_plugins.studies.validity`: do the metrics measure physics? (issues 9, 21, 32)
"""
