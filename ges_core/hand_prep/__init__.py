"""What the framework does to a hand's files so that every engine loads them as the hand means.

* :mod:`.mimic`: URDF ``<mimic>`` tags as couplings (multiplier and offset), and URDFs without them;
* :mod:`.meshes`: mesh paths resolved (``package://`` too) and formats converted to OBJ, cached by hash;
* :mod:`.engine_urdf`: the URDF both simulator plugins load (the three steps together);
* :mod:`.engine_files`: the plugins' engine-ready hand files, made once per process (light to import);
* :mod:`.geometry`: hull-vs-mesh measurements (what a single convex hull per link gets wrong);
* :mod:`.decompose`, :mod:`.prepare`: ``ges hand prepare``, CoACD where a hull is wrong, cached by mesh hash.

Submodules are imported where used (trimesh and CoACD are heavy); docs: ``docs/hands/assets.md``.
"""
