"""Generated VisPhyBench: scene specs, Box2D ground truth, exact rasteriser, dataset builders.

Import the submodules directly (`visphy_core.bench.spec`, `.box2d_sim`, `.raster2d`, ...): this
package deliberately imports nothing, so code that needs only the spec schema does not load Box2D.
"""
