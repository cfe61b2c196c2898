"""Generated VisPhyBench: templates, Box2D / cannon-es ground truth, exact rasteriser, builder.

The dataset plugin (``dataset.source=generated``) is `visphy_plugins.datasets.visphybench.plugin`.
Import the submodules directly (`.build`, `.raster2d`, `.templates_2d`...): this package imports
nothing, so code that needs one part does not load the rest.
"""
