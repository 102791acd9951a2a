"""Geometry: directions on the sphere, cube maps, the camera and ray queries.

- :mod:`lobelight.geometry.sphere`   the 92 geodesic views, Fibonacci and local direction sets,
  frames and rotations; the geodesic triangles each cube-map texel may hold
  (:func:`~lobelight.geometry.sphere.triangle_candidates`, kept on disk between processes)
- :mod:`lobelight.geometry.cubemap`  cube-map texel directions, exact solid angles, seamless
  bilinear sampling
- :mod:`lobelight.geometry.camera`   Mitsuba 3's perspective sensor (:class:`Camera`)
- :mod:`lobelight.geometry.raycast`  closest-hit and any-hit ray queries on a triangle mesh
  (:class:`RayCaster`), through Embree on the CPU or NVIDIA Warp on the CPU or a GPU

Conventions (directions, cube-map faces, the camera): ``docs/conventions.md``.
"""
