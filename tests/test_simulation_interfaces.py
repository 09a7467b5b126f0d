"""Our build of the standard simulator interfaces (ros2_ws/simulation_interfaces) is the
published Jazzy release 1.5.1 of github.com/ros-simulation/simulation_interfaces, so a client
built from the upstream package talks to `formic world`: every interface's type hash (RIHS01:
field names, types and nesting, what DDS endpoints compare) equals the hash computed from the
upstream 1.5.1 definition files, and the constants and defaults, which the hash leaves out,
are the upstream ones. A drift in a definition file fails here, with the type named."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("simulation_interfaces.srv")

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ros2_ws" / "simulation_interfaces"

# RIHS01 hashes generated (rosidl_generator_type_description) from the upstream 1.5.1 files
UPSTREAM_HASHES = {
    "action/SimulateSteps": "f0837c898e1219cd73bf4c041feab41e8c533e8e1057e982744dba7b093467eb",
    "msg/Bounds": "e8624fe51f0f5548197542697d924c5699ac7198f1e4c68e50c3ca2af73f5b3f",
    "msg/EntityCategory": "43bdf7933fddf75f6970f7a8fe7078524355d821d390b3954bb46ac36c03dfe1",
    "msg/EntityFilters": "8e7b12e8ea062f14c55de4877221fe1b7cd9749665a7ad8a4ab855fc4b148303",
    "msg/EntityInfo": "3b9a2e7fa00f9a59d325b6e47904044c421561a385682027c7fc06c359806319",
    "msg/EntityState": "2e0464a85eb80a939025075d6c20761eca6a4cb9d6baf2c0ba373467c8b598d0",
    "msg/NamedPose": "b32da2a039b1840f605ec025b7991a18efacac662fac272818d1ae6e2b12bc27",
    "msg/Resource": "2bb1939cf80f8d2f284afba53cbec60b5ff33759bd39b714128ea8867a34c51a",
    "msg/Result": "cf43a306adff3337a0a47143d8f5689933bc70a30478f13b077dc1fe3bc5ad17",
    "msg/SimulationState": "bb9f87ccdd98fba113052a512d9801e84ce732d0a2b3c2b0cb281828de36e415",
    "msg/SimulatorFeatures": "8b101c8529bc0ea3dcf056078254768f39832b9ef0adaf93bd5cea96c0de3305",
    "msg/SpawnEntity": "94a349a865ccf673c18c080520299c88c3d8d5f4842ecf1482d6c997ac4b69f9",
    "msg/SpawnResult": "dbc277304b6c24bfb2a631cea8f52e2b005d583ec0a6c86b11613f5ce6486da1",
    "msg/Spawnable": "8c22025d840e7a05ab31ba56f998b06458b549a9744b4695be25b778829fc176",
    "msg/TagsFilter": "5c3efc51e8ed04c266c09cb4691ec95b964cd410558e01d8c83646b038826b45",
    "msg/WorldResource": "e3b65ecf904b9b115673e4a343c6aa3d28c19e185a71228faa64b783afcf2403",
    "srv/DeleteEntity": "ff7e96a5b83dc8e2bb34b8b034480028b3a24d9f8376b2c0590bac3704be3e28",
    "srv/GetAvailableWorlds": "ce5589b5523f2732d1969a3c5a7e6b17a387091df8190c62f78d7fdd1109e3e3",
    "srv/GetCurrentWorld": "79ed4e910e1b7a1c9f7950ff758bfba3535bf0dec669054e8af115a099724ddd",
    "srv/GetEntities": "cb90004c48cd50f37732fb008e22c34c261dd680a723bf0f85d8437ea4498bf7",
    "srv/GetEntitiesStates": "0a76170d0c1c90e1eaf805cfab78ea801d1f82df309a28c1f0fae4b570f19754",
    "srv/GetEntityBounds": "17be8d36231178a5eed0de0344b55c19975581627a9aec30a4fee9926a35deed",
    "srv/GetEntityInfo": "953b7ab6bfc35063f5c9a72463c6ce489baa10249a7fa510926d342a34b0d29e",
    "srv/GetEntityState": "749c91f2a2353d98367b64f2995a0f5842ce92a08ec1ffb3e185540a91557fb5",
    "srv/GetNamedPoseBounds": "59fa8dd2c68ba6771160cc66a628ac99fa95e2748fa0a43c2cc62a2e5f3f6fdc",
    "srv/GetNamedPoses": "c3d12ab920115bfd4733f6d20516adc3968fb438538540997c37e200e02b04e3",
    "srv/GetSimulationState": "3362dcebee4b1afebbf9c4beee5c79c1455385aded62092a892d61fde8644f30",
    "srv/GetSimulatorFeatures": "abb9439c8cf196722a469fb6c68b44b484f198c2a1356ac38849a29c2a20a794",
    "srv/GetSpawnables": "3bc0266bf8236058ff589c44512e013afe4f295427c39d44cff363d1c956bf36",
    "srv/LoadWorld": "f210682338f195f6f06191b46b20ec4992bddf485d33e2cffab2dd15341b4e3e",
    "srv/ResetSimulation": "4ce285d7ff9b8ac70dcc95161f32bf54c05a6f4b13427990e41ab40c36c39646",
    "srv/SetEntityInfo": "867fe2b6812f3e021859171f9b788560d66bb7079d640030baf6c0bb2dd2631e",
    "srv/SetEntityState": "ca210e7d2b66629ae133c8e1edf5246e618106d75c78ed0556c0e7a33c59ee5e",
    "srv/SetSimulationState": "a868b916dce49974f637ba252141258c4b07b0c06858b88af560e3eb6bfbcb30",
    "srv/SpawnEntities": "41703a359ee032bf4fc230f144f531705ba039a2e97edeae1f7997dd83b04857",
    "srv/SpawnEntity": "d4c086345d4194a5fc4c9ae45095736ca4062b5cdac4d06a42dec93d683e03cf",
    "srv/StepSimulation": "913fe0653690ce6bf8f09f316e6a626747012e9fca31e26719910d417aa8565c",
    "srv/UnloadWorld": "ac7f9a73df1b5b15015d854c5ac552b7726506e22f886c6792804f0b7f88b30b",
}

# every constant of release 1.5.1, per message (services: request or response; action: goal, result, feedback)
UPSTREAM_CONSTANTS = {
    "msg/Bounds": {"TYPE_EMPTY": 0, "TYPE_BOX": 1, "TYPE_CONVEX_HULL": 2, "TYPE_SPHERE": 3},
    "msg/EntityCategory": {"CATEGORY_OBJECT": 0, "CATEGORY_ROBOT": 1, "CATEGORY_HUMAN": 2,
                           "CATEGORY_DYNAMIC_OBJECT": 4, "CATEGORY_STATIC_OBJECT": 5},
    "msg/Result": {"RESULT_FEATURE_UNSUPPORTED": 0, "RESULT_OK": 1, "RESULT_NOT_FOUND": 2,
                   "RESULT_INCORRECT_STATE": 3, "RESULT_OPERATION_FAILED": 4},
    "msg/SimulationState": {"STATE_STOPPED": 0, "STATE_PLAYING": 1, "STATE_PAUSED": 2, "STATE_QUITTING": 3,
                            "STATE_NO_WORLD": 4, "STATE_LOADING_WORLD": 5},
    "msg/SimulatorFeatures": {
        "SPAWNING": 0, "DELETING": 1, "NAMED_POSES": 2, "POSE_BOUNDS": 3, "ENTITY_TAGS": 4, "ENTITY_BOUNDS": 5,
        "ENTITY_BOUNDS_BOX": 6, "ENTITY_BOUNDS_CONVEX": 7, "ENTITY_CATEGORIES": 8, "SPAWNING_RESOURCE_STRING": 9,
        "ENTITY_STATE_GETTING": 10, "ENTITY_STATE_SETTING": 11, "ENTITY_INFO_GETTING": 12,
        "ENTITY_INFO_SETTING": 13, "SPAWNABLES": 14, "SIMULATION_RESET": 20, "SIMULATION_RESET_TIME": 21,
        "SIMULATION_RESET_STATE": 22, "SIMULATION_RESET_SPAWNED": 23, "SIMULATION_STATE_GETTING": 24,
        "SIMULATION_STATE_SETTING": 25, "SIMULATION_STATE_PAUSE": 26, "STEP_SIMULATION_SINGLE": 31,
        "STEP_SIMULATION_MULTIPLE": 32, "STEP_SIMULATION_ACTION": 33, "WORLD_LOADING": 40,
        "WORLD_RESOURCE_STRING": 41, "WORLD_TAGS": 42, "WORLD_UNLOADING": 43, "WORLD_INFO_GETTING": 44,
        "AVAILABLE_WORLDS": 45, "SPAWNING_ENTITIES": 50},
    "msg/SpawnResult": {"NAME_NOT_UNIQUE": 101, "NAME_INVALID": 102, "UNSUPPORTED_FORMAT": 103, "NO_RESOURCE": 104,
                        "NAMESPACE_INVALID": 105, "RESOURCE_PARSE_ERROR": 106, "MISSING_ASSETS": 107,
                        "UNSUPPORTED_ASSETS": 108, "INVALID_POSE": 109},
    "msg/TagsFilter": {"FILTER_MODE_ANY": 0, "FILTER_MODE_ALL": 1},
    "srv/GetAvailableWorlds.Response": {"DEFAULT_SOURCES_FAILED": 101},
    "srv/GetCurrentWorld.Response": {"NO_WORLD_LOADED": 101},
    "srv/LoadWorld.Response": {"UNSUPPORTED_FORMAT": 101, "NO_RESOURCE": 102, "RESOURCE_PARSE_ERROR": 103,
                               "MISSING_ASSETS": 104, "UNSUPPORTED_ASSETS": 105, "UNSUPPORTED_ELEMENTS": 106},
    "srv/ResetSimulation.Request": {"SCOPE_DEFAULT": 0, "SCOPE_TIME": 1, "SCOPE_STATE": 2, "SCOPE_SPAWNED": 4,
                                    "SCOPE_ALL": 255},
    "srv/SetEntityState.Response": {"INVALID_POSE": 101},
    "srv/SetSimulationState.Response": {"ALREADY_IN_TARGET_STATE": 101, "STATE_TRANSITION_ERROR": 102,
                                        "INCORRECT_TRANSITION": 103},
    "srv/SpawnEntities.Response": {"ENTITIES_SPAWN_FAILED": 150},
    "srv/SpawnEntity.Response": {"NAME_NOT_UNIQUE": 101, "NAME_INVALID": 102, "UNSUPPORTED_FORMAT": 103,
                                 "NO_RESOURCE": 104, "NAMESPACE_INVALID": 105, "RESOURCE_PARSE_ERROR": 106,
                                 "MISSING_ASSETS": 107, "UNSUPPORTED_ASSETS": 108, "INVALID_POSE": 109},
    "srv/UnloadWorld.Response": {"NO_WORLD_LOADED": 101},
}


def interface_class(name: str):
    """``msg/Result`` -> the generated class; ``srv/X.Request`` -> its request class."""
    kind_and_type, _, part = name.partition(".")
    kind, type_name = kind_and_type.split("/")
    cls = getattr(importlib.import_module(f"simulation_interfaces.{kind}"), type_name)
    return getattr(cls, part) if part else cls


def constants_of(cls) -> dict[str, int]:
    """The constants rosidl generated for a message class (kept by its metaclass)."""
    meta = type(cls)
    return dict(getattr(meta, f"_{meta.__name__}__constants"))


def installed_hash(name: str) -> str:
    """The RIHS01 hash of our build, from the type description it installed into the venv."""
    share = Path(sys.prefix) / "share" / "simulation_interfaces"
    kind, type_name = name.split("/")
    hashes = json.loads((share / kind / f"{type_name}.json").read_text())["type_hashes"]
    return next(h["hash_string"] for h in hashes if h["type_name"] == f"simulation_interfaces/{name}")


def test_the_package_holds_every_interface_of_the_release_and_nothing_else():
    files = {f"{p.parent.name}/{p.stem}" for p in PACKAGE.glob("*/*") if p.suffix in (".msg", ".srv", ".action")}
    assert files == set(UPSTREAM_HASHES)
    assert "<version>1.5.1</version>" in (PACKAGE / "package.xml").read_text()


@pytest.mark.parametrize("name", sorted(UPSTREAM_HASHES))
def test_type_hash_equals_upstream(name):
    assert installed_hash(name) == f"RIHS01_{UPSTREAM_HASHES[name]}", (
        f"simulation_interfaces/{name} differs from release 1.5.1 in its fields: rebuild (scripts/setup.sh) "
        f"or fix ros2_ws/simulation_interfaces/{name}.*")


def test_constants_and_defaults_equal_upstream():
    for name, expected in UPSTREAM_CONSTANTS.items():
        assert constants_of(interface_class(name)) == expected, name
    parts = {"msg": [""], "srv": [".Request", ".Response"], "action": [".Goal", ".Result", ".Feedback"]}
    for name in UPSTREAM_HASHES:  # and none has a constant that upstream has not
        for part in parts[name.split("/")[0]]:
            if name + part not in UPSTREAM_CONSTANTS:
                assert constants_of(interface_class(name + part)) == {}, name + part
    assert interface_class("srv/StepSimulation.Request")().steps == 1  # the one default value of the release
