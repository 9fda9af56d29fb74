"""Hostile attempts for the robot models read from MENAGERIE_ROOT: a model that would hang MuJoCo's parse (6) and a
model that names files outside the robot's folder (16).

Each snippet runs after benchmarks/hostile.py's PRELUDE in a fresh interpreter and an empty temporary folder; it
builds its own MENAGERIE_ROOT there (``menagerie/trossen_wx250s/wx250s.xml``: a 6-joint arm written as Menagerie
writes arms, with the hostile part) and sets the variable before calling the CLI or the API.
"""

from __future__ import annotations

# The arm, and a helper that writes it with its hostile parts ({compiler}, {top}, {asset}, {world}) into the
# root; "secret/" beside the root holds the files an escaping model points at.
_SETUP = '''
import time
from seqmotion.sim.robot_models import get_robot
ARM = """<mujoco model="tiny">
  <compiler angle="radian" autolimits="true" {compiler}/>
  {top}
  <asset>{asset}</asset>
  <worldbody>
    {world}
    <body name="base">
      <body name="link1" pos="0 0 0.1">
        <joint name="s" axis="0 0 1" range="-2.8 2.8"/>
        <inertial pos="0 0 0.1" mass="3" diaginertia="0.03 0.03 0.01"/>
        <body name="link2" pos="0 0 0.25">
          <joint name="l" axis="0 1 0" range="-2.8 2.8"/>
          <inertial pos="0 0 0.15" mass="2" diaginertia="0.02 0.02 0.004"/>
          <body name="link3" pos="0 0 0.3">
            <joint name="u" axis="0 1 0" range="-2.8 2.8"/>
            <inertial pos="0.12 0 0" mass="1.5" diaginertia="0.002 0.008 0.008"/>
            <body name="link4" pos="0.1 0 0">
              <joint name="r" axis="1 0 0" range="-2.8 2.8"/>
              <inertial pos="0.1 0 0" mass="0.8" diaginertia="0.001 0.003 0.003"/>
              <body name="link5" pos="0.18 0 0">
                <joint name="b" axis="0 1 0" range="-2.8 2.8"/>
                <inertial pos="0.02 0 0" mass="0.4" diaginertia="0.0004 0.0004 0.0004"/>
                <body name="link6" pos="0.06 0 0">
                  <joint name="t" axis="1 0 0" range="-3 3"/>
                  <inertial pos="0.01 0 0" mass="0.2" diaginertia="0.0002 0.0002 0.0002"/>
                  <site name="attachment_site" pos="0.02 0 0" quat="1 0 1 0"/>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="a_s" joint="s" kp="300" forcerange="-40 40"/>
    <position name="a_l" joint="l" kp="300" forcerange="-60 60"/>
    <position name="a_u" joint="u" kp="200" forcerange="-30 30"/>
    <position name="a_r" joint="r" kp="50" forcerange="-12 12"/>
    <position name="a_b" joint="b" kp="50" forcerange="-12 12"/>
    <position name="a_t" joint="t" kp="50" forcerange="-5 5"/>
  </actuator>
</mujoco>
"""
FLEX = '<flexcomp name="sheet" type="grid" count="300 300 1" spacing="0.01 0.01 0.01" dim="2"/>'
OBJ = "v 0 0 0\\nv 0.01 0 0\\nv 0 0.01 0\\nv 0 0 0.01\\nf 1 2 3\\nf 1 2 4\\nf 1 3 4\\nf 2 3 4\\n"
SECRET = Path("secret").resolve()
SECRET.mkdir()
(SECRET / "frag.xml").write_text('<mujoco><asset><texture name="stolen" type="2d" builtin="checker" width="8" '
                                 'height="8"/></asset></mujoco>')
(SECRET / "m.obj").write_text(OBJ)
def menagerie(**parts):
    folder = Path("menagerie") / "trossen_wx250s"
    folder.mkdir(parents=True, exist_ok=True)
    text = ARM
    for key in ("compiler", "top", "asset", "world"):
        text = text.replace("{" + key + "}", parts.get(key, "").replace("SECRET", str(SECRET)))
    (folder / "wx250s.xml").write_text(text)
    os.environ["MENAGERIE_ROOT"] = str(Path("menagerie").resolve())
    return folder
np.savez("t.npz", states=sketches.straight((0.1, 0.0, 2.0), 150))
start = time.perf_counter()
'''

_ROBOT = "menagerie:trossen_wx250s"

ATTEMPTS: dict[int, list[tuple[str, str]]] = {
    6: [
        ("robots: a 300 x 300 flexcomp in the root", _SETUP + """
menagerie(world=FLEX)
rc, err = cli("robots")
seconds = time.perf_counter() - start
held(rc == 0 and seconds < 60, f"rc {rc} after {seconds:.0f} s: {err[-200:]}")
"""),
        ("simulate --robot typo: a 300 x 300 flexcomp in the root", _SETUP + """
menagerie(world=FLEX)
rc, err = cli("simulate", "pancake", "--trajectory", "t.npz", "--robot", "typo")
seconds = time.perf_counter() - start
held(rc == 2 and "unknown robot 'typo'" in err and err.count("\\n") == 1 and seconds < 60,
     f"rc {rc} after {seconds:.0f} s: {err[-200:]}")
"""),
        ("simulate --robot menagerie: its 300 x 300 flexcomp", _SETUP + f"""
menagerie(world=FLEX)
rc, err = cli("simulate", "pancake", "--trajectory", "t.npz", "--robot", "{_ROBOT}")
seconds = time.perf_counter() - start
held(rc == 2 and "flexcomp 'sheet'" in err and "90000" in err and err.count("\\n") == 1 and seconds < 60,
     f"rc {{rc}} after {{seconds:.0f}} s: {{err[-200:]}}")
"""),
        ("view --robot menagerie: its 300 x 300 flexcomp", _SETUP + f"""
menagerie(world=FLEX)
rc, err = cli("view", "--robot", "{_ROBOT}", "--port", "0", "--seconds", "0")
seconds = time.perf_counter() - start
held(rc == 2 and "flexcomp 'sheet'" in err and err.count("\\n") == 1 and seconds < 60,
     f"rc {{rc}} after {{seconds:.0f}} s: {{err[-200:]}}")
"""),
        ("API get_robot: 1000 x 1000 nested replicates", _SETUP + f"""
menagerie(world='<replicate count="1000" offset="0.01 0 0"><replicate count="1000" offset="0 0.01 0">'
                '<body><geom size="0.001"/></body></replicate></replicate>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "replicate" in message and "wx250s.xml" in message, str(message))
"""),
        ("API get_robot: a billion-laughs entity bomb", _SETUP + f"""
folder = menagerie()
lol = "".join(f'<!ENTITY l{{i}} "{{f"&l{{i - 1}};" * 10 if i else "lol"}}">' for i in range(10))
text = (folder / "wx250s.xml").read_text().replace('model="tiny"', 'model="&l9;"')
(folder / "wx250s.xml").write_text(f'<?xml version="1.0"?>\\n<!DOCTYPE m [{{lol}}]>\\n' + text)
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "DOCTYPE" in message and "wx250s.xml" in message, str(message))
"""),
        ("API get_robot: a texture of 1e10 pixels", _SETUP + f"""
menagerie(asset='<texture name="t" type="2d" builtin="checker" width="100000" height="100000"/>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "texture 't'" in message and "pixels" in message, str(message))
"""),
    ],
    16: [
        ("API get_robot: <include> of an absolute path", _SETUP + f"""
menagerie(top='<include file="SECRET/frag.xml"/>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "include" in message and "absolute" in message, str(message))
"""),
        ("API get_robot: <include> climbing out with ../", _SETUP + f"""
menagerie(top='<include file="../../secret/frag.xml"/>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "include" in message and "outside" in message, str(message))
"""),
        ("API get_robot: an absolute include inside an include", _SETUP + f"""
folder = menagerie(top='<include file="parts/inner.xml"/>')
(folder / "parts").mkdir()
(folder / "parts" / "inner.xml").write_text(f'<mujoco><include file="{{SECRET}}/frag.xml"/></mujoco>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "inner.xml" in message and "absolute" in message, str(message))
"""),
        ("API get_robot: an absolute mesh file", _SETUP + f"""
menagerie(asset='<mesh name="m" file="SECRET/m.obj"/>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "mesh" in message and "absolute" in message, str(message))
"""),
        ("API get_robot: an absolute compiler meshdir", _SETUP + f"""
menagerie(compiler='meshdir="SECRET"', asset='<mesh name="m" file="m.obj"/>')
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "meshdir" in message and "absolute" in message, str(message))
"""),
        ("API get_robot: a mesh symlinked out of the root", _SETUP + f"""
folder = menagerie(asset='<mesh name="m" file="m.obj"/>')
(folder / "m.obj").symlink_to(SECRET / "m.obj")
message = refused(get_robot, "{_ROBOT}")
held(message is not None and "m.obj" in message and "outside" in message, str(message))
"""),
        ("simulate --robot menagerie: an absolute include", _SETUP + f"""
menagerie(top='<include file="SECRET/frag.xml"/>')
rc, err = cli("simulate", "pancake", "--trajectory", "t.npz", "--robot", "{_ROBOT}")
held(rc == 2 and "include" in err and "absolute" in err and err.count("\\n") == 1, f"rc {{rc}}: {{err[-200:]}}")
"""),
    ],
}
