"""An example third-party visphy plugin: one small, working module per plugin kind.

Each module is its own ``visphy`` entry point (``pyproject.toml``), so each is a plugin on its
own in ``visphy plugins`` and can be switched off alone (``VISPHY_DISABLE_PLUGINS``):

========================  ========================================================
``configs``               config-group entries: ``model=example_still``, ``engine=example_boxes``,
                          ``judge=example_pixels``
``model``                 model ``example_still``: the first key frame held (no API key)
``engine``                engine ``example_boxes``: boxes in free flight, drawn with numpy
``metric``                metric ``example_mae``: mean absolute pixel difference
``judge``                 judge ``example_pixels``: a 1–10 verdict from the pixel difference
``dataset``               dataset ``example_squares``: three falling squares, written on first use
``physics``               simulator ``example_euler``: point masses under gravity, no contacts
``lifecycle``             run hooks: one line per scene in the run's ``example_log.jsonl``
========================  ========================================================
"""
