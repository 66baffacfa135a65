"""Bone naming conventions seen in real rigs, so name-based logic (the Mixamo template
matcher) and name-blind models both see the variety they will meet."""

from __future__ import annotations

import numpy as np

MIXAMO_FINGERS = ["Thumb", "Index", "Middle", "Ring", "Pinky"]

# Humanoid body keys -> names. `{s}` is the side word of the style, `{k}` a 1-based index.
HUMANOID_STYLES = {
    "blender": {
        "root": "root", "hips": "hips", "spine": ["spine", "chest", "upper_chest", "spine.004"],
        "neck": "neck", "head": "head", "headtop": "head_end",
        "shoulder": "shoulder.{S}", "arm": "upper_arm.{S}", "forearm": "forearm.{S}", "hand": "hand.{S}",
        "upleg": "thigh.{S}", "leg": "shin.{S}", "foot": "foot.{S}", "toe": "toe.{S}", "toeend": "toe_end.{S}",
        "finger": "{f}.0{k}.{S}", "fingers": ["thumb", "f_index", "f_middle", "f_ring", "f_pinky"],
        "side": {"L": "L", "R": "R"},
    },
    "dotted": {
        "root": "Root", "hips": "Hips", "spine": ["Spine", "Chest", "UpperChest", "Spine.003"],
        "neck": "Neck", "head": "Head", "headtop": "Head.end",
        "shoulder": "Shoulder.{S}", "arm": "UpperArm.{S}", "forearm": "LowerArm.{S}", "hand": "Hand.{S}",
        "upleg": "UpperLeg.{S}", "leg": "LowerLeg.{S}", "foot": "Foot.{S}", "toe": "Toes.{S}", "toeend": "Toes.end.{S}",
        "finger": "{f}{k}.{S}", "fingers": ["Thumb", "Index", "Middle", "Ring", "Little"],
        "side": {"L": "L", "R": "R"},
    },
    "underscore": {
        "root": "Root", "hips": "Hips", "spine": ["Spine", "Chest", "Chest2", "Chest3"],
        "neck": "Neck", "head": "Head", "headtop": "Head_End",
        "shoulder": "Shoulder_{S}", "arm": "UpperArm_{S}", "forearm": "Forearm_{S}", "hand": "Hand_{S}",
        "upleg": "Thigh_{S}", "leg": "Shin_{S}", "foot": "Foot_{S}", "toe": "Toe_{S}", "toeend": "Toe_End_{S}",
        "finger": "{f}_{k}_{S}", "fingers": ["Thumb", "Index", "Middle", "Ring", "Pinky"],
        "side": {"L": "L", "R": "R"},
    },
    "unreal": {
        "root": "root", "hips": "pelvis", "spine": ["spine_01", "spine_02", "spine_03", "spine_04"],
        "neck": "neck_01", "head": "head", "headtop": "head_end",
        "shoulder": "clavicle_{S}", "arm": "upperarm_{S}", "forearm": "lowerarm_{S}", "hand": "hand_{S}",
        "upleg": "thigh_{S}", "leg": "calf_{S}", "foot": "foot_{S}", "toe": "ball_{S}", "toeend": "ball_end_{S}",
        "finger": "{f}_0{k}_{S}", "fingers": ["thumb", "index", "middle", "ring", "pinky"],
        "side": {"L": "l", "R": "r"},
    },
    "biped": {
        "root": "Bip01", "hips": "Bip01 Pelvis", "spine": ["Bip01 Spine", "Bip01 Spine1", "Bip01 Spine2", "Bip01 Spine3"],
        "neck": "Bip01 Neck", "head": "Bip01 Head", "headtop": "Bip01 HeadNub",
        "shoulder": "Bip01 {S} Clavicle", "arm": "Bip01 {S} UpperArm", "forearm": "Bip01 {S} Forearm",
        "hand": "Bip01 {S} Hand", "upleg": "Bip01 {S} Thigh", "leg": "Bip01 {S} Calf", "foot": "Bip01 {S} Foot",
        "toe": "Bip01 {S} Toe0", "toeend": "Bip01 {S} Toe0Nub",
        "finger": "Bip01 {S} Finger{f}{k0}", "fingers": ["0", "1", "2", "3", "4"],
        "side": {"L": "L", "R": "R"},
    },
    "vroid": {
        "root": "Root", "hips": "J_Bip_C_Hips", "spine": ["J_Bip_C_Spine", "J_Bip_C_Chest", "J_Bip_C_UpperChest", "J_Bip_C_Spine4"],
        "neck": "J_Bip_C_Neck", "head": "J_Bip_C_Head", "headtop": "J_Adj_C_HeadTop",
        "shoulder": "J_Bip_{S}_Shoulder", "arm": "J_Bip_{S}_UpperArm", "forearm": "J_Bip_{S}_LowerArm",
        "hand": "J_Bip_{S}_Hand", "upleg": "J_Bip_{S}_UpperLeg", "leg": "J_Bip_{S}_LowerLeg",
        "foot": "J_Bip_{S}_Foot", "toe": "J_Bip_{S}_ToeBase", "toeend": "J_Bip_{S}_ToeEnd",
        "finger": "J_Bip_{S}_{f}{k}", "fingers": ["Thumb", "Index", "Middle", "Ring", "Little"],
        "side": {"L": "L", "R": "R"},
    },
    "camel": {
        "root": "Root", "hips": "Pelvis", "spine": ["Spine", "Spine1", "Spine2", "Spine3"],
        "neck": "Neck", "head": "Head", "headtop": "HeadEnd",
        "shoulder": "{S}Clavicle", "arm": "{S}UpperArm", "forearm": "{S}Forearm", "hand": "{S}Hand",
        "upleg": "{S}Thigh", "leg": "{S}Calf", "foot": "{S}Foot", "toe": "{S}Toe", "toeend": "{S}ToeEnd",
        "finger": "{S}{f}{k}", "fingers": ["Thumb", "Index", "Middle", "Ring", "Pinky"],
        "side": {"L": "Left", "R": "Right"},
    },
}


class HumanoidNames:
    """Names for humanoid body keys in one style; `mixamo` follows Mixamo exactly."""

    def __init__(self, style: str, prefix: str = "mixamorig:"):
        self.style = style
        self.prefix = prefix
        self.counter = 0

    def get(self, key: str, side: str | None = None, idx: int = 0, finger: int = 0) -> str:
        if self.style == "mixamo":
            return self.prefix + self._mixamo(key, side, idx, finger)
        if self.style in ("generic", "maya"):
            self.counter += 1
            if self.style == "generic":
                return "Bone" if self.counter == 1 else f"Bone.{self.counter - 1:03d}"
            return f"joint{self.counter}"
        st = HUMANOID_STYLES[self.style]
        S = st["side"][side] if side else ""
        if key == "spine":
            names = st["spine"]
            return names[idx] if idx < len(names) else f"{names[0]}{idx}"
        if key == "finger":
            f = st["fingers"][finger]
            return st["finger"].format(f=f, k=idx + 1, k0="" if idx == 0 else idx, S=S)
        return st[key].format(S=S)

    @staticmethod
    def _mixamo(key, side, idx, finger):
        sw = {"L": "Left", "R": "Right", None: ""}[side]
        table = {
            "hips": "Hips", "neck": "Neck", "head": "Head", "headtop": "HeadTop_End",
            "shoulder": f"{sw}Shoulder", "arm": f"{sw}Arm", "forearm": f"{sw}ForeArm", "hand": f"{sw}Hand",
            "upleg": f"{sw}UpLeg", "leg": f"{sw}Leg", "foot": f"{sw}Foot", "toe": f"{sw}ToeBase",
            "toeend": f"{sw}Toe_End", "root": "Root",
        }
        if key == "spine":
            return "Spine" if idx == 0 else f"Spine{idx}"
        if key == "finger":
            return f"{sw}Hand{MIXAMO_FINGERS[finger]}{idx + 1}"
        return table[key]


class Namer:
    """Generic creature/prop naming: `namer("leg", "L", 2)` → `Leg_L_02`, `leg.L.002`, …"""

    STYLES = ["under", "dot", "prefix", "camel", "lower", "generic", "maya", "def"]

    def __init__(self, rng: np.random.Generator, style: str | None = None):
        self.style = style or str(rng.choice(self.STYLES, p=[0.22, 0.2, 0.12, 0.14, 0.14, 0.08, 0.05, 0.05]))
        self.n = 0

    def __call__(self, base: str, side: str | None = None, idx: int | None = None) -> str:
        self.n += 1
        st = self.style
        if st == "generic":
            return "Bone" if self.n == 1 else f"Bone.{self.n - 1:03d}"
        if st == "maya":
            return f"joint{self.n}"
        words = base.replace("-", "_").split("_")
        if st == "under":
            s = "_".join(w.capitalize() for w in words)
            if side:
                s += f"_{side}"
            if idx is not None:
                s += f"_{idx:02d}"
            return s
        if st == "dot":
            s = "_".join(words).lower()
            if idx is not None:
                s += f".{idx:03d}"
            if side:
                s += f".{side}"
            return s
        if st == "prefix":
            s = "".join(w.capitalize() for w in words)
            if idx is not None:
                s += str(idx)
            return f"{side}_{s}" if side else s
        if st == "camel":
            sw = {"L": "Left", "R": "Right"}.get(side or "", side or "")
            s = sw + "".join(w.capitalize() for w in words)
            if idx is not None:
                s += str(idx)
            return s
        if st == "lower":
            s = "_".join(words).lower()
            if side:
                s += "_" + side.lower()
            if idx is not None:
                s += f"_{idx}"
            return s
        # def: Rigify deform bones
        s = "DEF-" + "_".join(words).lower()
        if idx is not None:
            s += f".{idx:03d}"
        if side:
            s += f".{side}"
        return s
