"""pbdyn.world: what the MAV flies in (docs/architecture.md "Layers").

maps.py (map enumeration, seeds, spawning) and structure.py (structured maps) make a generated map; rollout.py runs
its obstacles through their motion model (pbdyn.motion) into a cached Rollout; imported/ is the URDF world (URDF
loading and scaling, imported bodies and their scripted motions; motions.py holds the example motion functions);
shapes.py the signed-distance fields of the bodies' real shapes; geometry.py the generated static bodies;
bullet.py the PyBullet world of a trial or metric run, pybullet_client.py PyBullet itself (import, clients, display).
draws.py holds the random draws (values, spreads, headings) that maps.py and structure.py spawn from.
"""
