"""Human evaluation: a model-blind rating page served on localhost (``python -m visphy_core rate``).

The paper's holistic scores include human 1–5 ratings. A rater sees, for one item at
a time, the ground-truth clip and ONE generated clip, and gives a rating from 1 to 5 with an
optional comment. What the page may learn is limited to what the rating needs: opaque item ids
and video URLs, never a model, engine or run name (`items`). The order is shuffled by a seed
derived from the rater id, so a rater who comes back resumes the same order, and items the rater
already rated are skipped. Ratings are appended to ``<run_dir>/human_ratings.jsonl`` (`store`),
the file the leaderboard's Human column is computed from.

Modules: `items` (which videos to rate, their ids and order), `store` (the ratings file),
`media` (browser-playable copies and HTTP range requests), `server` (the HTTP endpoints and
their checks) and ``page.html`` (the page itself).
"""
