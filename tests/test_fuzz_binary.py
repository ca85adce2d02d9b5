"""Fuzzing of makeway's binary readers (issue 29, item 1): video files, images (JPEG and PNG crops,
YOLO set images), model files (ONNX crop classifiers and siren models, the EV head ``.npz``, the
roadside location reference ``.npz``), and V2X: alert bodies, signed alerts as a car receives them,
unit keys and certificates, trust stores. Each generated input ends in a result or one
``InputError`` naming the file (:func:`fuzzing.check_reader`); a V2X message never raises at all —
the car answers every byte string with a verdict."""

from __future__ import annotations

import io
import shutil
import struct
import time
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from conftest import require_module
from fuzzing import NASTY, budget, check_reader, file_contents, mutated_bytes
from makeway.errors import InputError
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.vision.efficientnet_lite import read_torch_state_dict
from makeway.perceive.vision.ev_classifier import SHIPPED_MODELS, EVCropClassifier, load_crop_classifier
from makeway.perceive.vision.light_cnn import CnnLightDetector, default_lights_model
from makeway.perceive.vision.light_verify import DEFAULT_VERIFIER_MODEL, LightVerifier
from makeway.roadside.reference import LocationReference, load_reference
from makeway.roadside.simulated import SIM_ORIGIN, sim_pairs
from makeway.sense.crops import read_crop_folder, read_yolo_set
from makeway.sense.video import VideoReader
from makeway.v2x.message import ALERT_SIZE, Alert, MalformedAlertError, decode_alert, encode_alert
from makeway.v2x.security import TrustStore, Verdict, Verifier, keygen, load_identity, sign_alert

MODELS = Path(SHIPPED_MODELS["fastest"]).parent


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_binary")


def _write(folder: Path, name: str, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_bytes(data)
    return path


# -------------------------------------------------------------------------------------------- video
@pytest.fixture(scope="module")
def small_clip(video_dir: Path, work: Path) -> bytes:
    """The first 12 frames of a real clip, 96×72, H.264 in MP4 (a few kB)."""
    out = io.BytesIO()
    with (
        av.open(str(video_dir / "highway_cam_no_ev.mp4")) as src,
        av.open(out, mode="w", format="mp4") as dst,
    ):
        stream = dst.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 96, 72, "yuv420p"
        for i, frame in enumerate(src.decode(video=0)):
            if i == 12:
                break
            small = cv2.resize(frame.to_ndarray(format="bgr24"), (96, 72), interpolation=cv2.INTER_AREA)
            dst.mux(stream.encode(av.VideoFrame.from_ndarray(small, format="bgr24")))
        dst.mux(stream.encode(None))
    return out.getvalue()


def test_fuzz_video(small_clip: bytes, work: Path) -> None:
    def read_all(path: Path) -> int:
        with VideoReader(path) as reader:
            n = sum(1 for _ in reader)
            reader.check_complete()
        return n

    @budget(0.5)
    @given(data=file_contents(small_clip, "binary"))
    def run(data: bytes) -> None:
        path = _write(work / "video", "clip.mp4", data)
        got = check_reader("video file (MP4)", lambda: read_all(path), inside=path)
        assert got is None or got >= 1

    run()


# ------------------------------------------------------------------------------------------- images
def test_fuzz_crop_images(data_root: Path, work: Path) -> None:
    source = data_root / "vision" / "ev_crops" / "images"
    jpeg = sorted(source.iterdir())[0].read_bytes()
    ok, png = cv2.imencode(
        ".png", cv2.resize(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR), (48, 48))
    )
    assert ok
    seeds = {"jpg": jpeg, "png": png.tobytes()}
    root = work / "crop_images"

    @budget(0.5)
    @given(suffix=st.sampled_from(sorted(seeds)), data=st.data())
    def run(suffix: str, data: st.DataObject) -> None:
        shutil.rmtree(root, ignore_errors=True)
        _write(root / "images", f"a.{suffix}", data.draw(file_contents(seeds[suffix], "binary")))
        _write(root, "labels.csv", f"image,emergency\na.{suffix},1\n".encode())

        def load() -> np.ndarray:
            return read_crop_folder(root).load_images(32)

        got = check_reader(f"image file ({suffix.upper()})", load, inside=root)
        assert got is None or got.shape == (1, 32, 32, 3)

    run()


def test_fuzz_yolo_set_images(data_root: Path, work: Path) -> None:
    valid = data_root / "vision" / "ambulance_yolo" / "valid"
    label = sorted((valid / "labels").iterdir())[0]
    image = cv2.imread(str(valid / "images" / (label.stem + ".jpg")))
    ok, small = cv2.imencode(".jpg", cv2.resize(image, (80, 80)))
    assert ok
    root = work / "yolo_images"
    _write(root / "labels", "a.txt", label.read_bytes())

    @budget(0.5)
    @given(data=file_contents(small.tobytes(), "binary"))
    def run(data: bytes) -> None:
        _write(root / "images", "a.jpg", data)
        got = check_reader("image file (YOLO set)", lambda: read_yolo_set(root), inside=root)
        assert got is None or (got[0].width > 0 and got[0].height > 0)

    run()


# ------------------------------------------------------------------------------------------- models
@st.composite
def mutated_onnx(draw: st.DrawFn, seed: bytes) -> bytes:
    """An ONNX model parsed and edited where a loader looks: a metadata value replaced or removed, an
    input's or output's declared shape changed, an operator renamed, a node or weight removed, a
    weight's bytes cut short; serialised again."""
    import onnx

    model = onnx.load_from_string(seed)
    graph = model.graph
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["meta", "meta", "drop_meta", "shape", "op_type", "drop_node", "weight"]))
        if op == "meta" and model.metadata_props:
            prop = draw(st.sampled_from(list(model.metadata_props)))
            prop.value = draw(st.sampled_from(NASTY) | st.text(max_size=20))
        elif op == "drop_meta" and model.metadata_props:
            del model.metadata_props[draw(st.integers(0, len(model.metadata_props) - 1))]
        elif op == "shape":
            value = draw(st.sampled_from([*graph.input, *graph.output]))
            dims = value.type.tensor_type.shape.dim
            if dims:
                dim = dims[draw(st.integers(0, len(dims) - 1))]
                dim.dim_value = draw(st.sampled_from([0, 1, 2, 3, 7, 4096]))
        elif op == "op_type" and graph.node:
            graph.node[draw(st.integers(0, len(graph.node) - 1))].op_type = draw(
                st.sampled_from(["Relu", "Add", "Identity", "Softmax", "NoSuchOp"])
            )
        elif op == "drop_node" and graph.node:
            del graph.node[draw(st.integers(0, len(graph.node) - 1))]
        elif op == "weight" and graph.initializer:
            init = graph.initializer[draw(st.integers(0, len(graph.initializer) - 1))]
            if init.raw_data:
                init.raw_data = init.raw_data[: draw(st.integers(0, len(init.raw_data)))]
    return model.SerializeToString()


def model_contents(seed: bytes) -> st.SearchStrategy[bytes]:
    """Generated model files: mostly structure-aware edits, some byte-level, some random bytes."""
    return st.one_of(mutated_onnx(seed), mutated_onnx(seed), mutated_bytes(seed), st.binary(max_size=256))


def test_fuzz_onnx_crop_classifier(work: Path) -> None:
    seed = (MODELS / "ev_cnn_small32.onnx").read_bytes()
    crops = np.random.default_rng(0).integers(0, 256, (2, 32, 32, 3), dtype=np.uint8)

    @budget(0.25)
    @given(data=model_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "onnx_cnn", "model.onnx", data)

        def load_and_score() -> np.ndarray:
            model = load_crop_classifier(path, num_threads=1)
            return np.asarray(model.predict_proba(crops))

        got = check_reader("model file (ONNX crop classifier)", load_and_score, inside=path)
        assert got is None or got.shape == (2,)

    run()


def test_fuzz_onnx_siren_model(work: Path) -> None:
    """The siren network as ``audio listen`` loads it: ONNX, its metadata (streams, feature settings
    as JSON, threshold, calibration) and inputs checked against each other."""
    seed = (MODELS / "siren_net.onnx").read_bytes()

    @budget(0.25)
    @given(data=model_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "onnx_siren", "siren.onnx", data)
        check_reader("model file (ONNX siren model)", lambda: SirenModel(path, threads=1), inside=path)

    run()


def test_fuzz_onnx_light_detector(work: Path) -> None:
    seed = default_lights_model().read_bytes()

    @budget(0.25)
    @given(data=model_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "onnx_lights", "lights.onnx", data)
        check_reader(
            "model file (ONNX light detector)",
            lambda: CnnLightDetector(model=path, num_threads=1),
            inside=path,
        )

    run()


def test_fuzz_onnx_light_verifier(work: Path) -> None:
    seed = DEFAULT_VERIFIER_MODEL.read_bytes()

    @budget(0.25)
    @given(data=model_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "onnx_verifier", "verifier.onnx", data)
        check_reader("model file (ONNX light verifier)", lambda: LightVerifier(path), inside=path)

    run()


@pytest.fixture(scope="module")
def torch_weights(work: Path) -> dict[str, bytes]:
    """A small ``state_dict`` saved by torch in both of its formats (zip and legacy pickle)."""
    torch = require_module("torch")
    state = {
        "conv.weight": torch.arange(24, dtype=torch.float32).reshape(2, 3, 2, 2),
        "bn.num": torch.tensor(7),
    }
    out = {}
    for fmt, zipped in (("zip", True), ("legacy", False)):
        path = work / f"weights_{fmt}.pt"
        torch.save(state, path, _use_new_zipfile_serialization=zipped)
        out[fmt] = path.read_bytes()
    return out


def test_fuzz_torch_weights(torch_weights: dict[str, bytes], work: Path) -> None:
    """The pretrained-weights reader unpickles without torch and refuses anything but tensors: it
    must never run code or fail otherwise, whatever the bytes."""

    @budget(0.5)
    @given(fmt=st.sampled_from(sorted(torch_weights)), data=st.data())
    def run(fmt: str, data: st.DataObject) -> None:
        path = _write(work / "torch", "weights.pt", data.draw(file_contents(torch_weights[fmt], "binary")))
        got = check_reader(
            f"model file (PyTorch weights, {fmt})", lambda: read_torch_state_dict(path), inside=path
        )
        if got is not None:
            assert all(isinstance(v, np.ndarray) for v in got.values())

    run()


_npz_value = st.one_of(
    st.just(np.array(np.nan)),
    st.just(np.array([np.inf, -np.inf])),
    st.just(np.zeros((0,))),
    st.just(np.array("text")),
    st.just(np.array([1, 2, 3], dtype=np.int8)),
    st.just(np.ones((2, 3, 4), dtype=np.float32)),
    st.integers(-(2**40), 2**40).map(np.array),
    st.floats().map(np.array),
)


@st.composite
def mutated_npz(draw: st.DrawFn, seed: bytes) -> bytes:
    """An ``.npz`` whose arrays are edited: one dropped, replaced by another type or shape, or NaN."""
    with np.load(io.BytesIO(seed), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from(sorted(arrays)))
        op = draw(st.sampled_from(["replace", "drop", "nan", "reshape"]))
        if op == "replace":
            arrays[key] = draw(_npz_value)
        elif op == "drop" and len(arrays) > 1:
            del arrays[key]
        elif op == "nan" and arrays[key].dtype.kind == "f" and arrays[key].size:
            arrays[key] = arrays[key].copy()
            arrays[key].flat[draw(st.integers(0, arrays[key].size - 1))] = np.nan
        elif op == "reshape":
            arrays[key] = arrays[key].reshape(-1)[: draw(st.integers(0, arrays[key].size))]
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def test_fuzz_ev_head(work: Path) -> None:
    seed = Path(SHIPPED_MODELS["default"]).read_bytes()

    def npz(**edits: object) -> bytes:
        with np.load(io.BytesIO(seed)) as z:
            arrays = {k: z[k] for k in z.files}
        buf = io.BytesIO()
        np.savez(buf, **{**arrays, **edits})
        return buf.getvalue()

    @budget(0.25)
    @given(data=mutated_npz(seed) | mutated_bytes(seed) | st.binary(max_size=256))
    @example(data=npz(C=np.ones(3)))  # found by fuzzing: C was read outside the checks (TypeError)
    def run(data: bytes) -> None:
        path = _write(work / "ev_head", "head.npz", data)
        check_reader(
            "model file (EV head .npz)", lambda: EVCropClassifier.load(path, num_threads=1), inside=path
        )

    run()


def test_fuzz_location_reference(work: Path) -> None:
    pixels, xy = sim_pairs()
    seed_path = work / "reference_seed.npz"
    LocationReference(pixels[:40], xy[:40], SIM_ORIGIN).save(seed_path)
    seed = seed_path.read_bytes()

    def npz(**edits: object) -> bytes:
        with np.load(io.BytesIO(seed)) as z:
            arrays = {k: z[k] for k in z.files}
        buf = io.BytesIO()
        np.savez(buf, **{**arrays, **edits})
        return buf.getvalue()

    @budget(0.5)
    @given(data=mutated_npz(seed) | mutated_bytes(seed) | st.binary(max_size=256))
    # found by fuzzing: an empty file (EOFError), a damaged zip (BadZipFile), a smoothing that is not one
    # number (TypeError), pairs whose map is not finite (a result of NaN)
    @example(data=b"")
    @example(data=b"PK\x03\x04" + bytes(60))
    @example(data=npz(smoothing=np.ones(3)))
    @example(data=npz(smoothing=np.array(np.nan)))
    @example(data=npz(pixels=pixels[:40] * 1e300))
    @example(data=npz(xy=np.array("text")))
    def run(data: bytes) -> None:
        path = _write(work / "reference", "reference.npz", data)
        got = check_reader("roadside location reference (.npz)", lambda: load_reference(path), inside=path)
        if got is not None:
            assert np.isfinite(got.locate(pixels[:3])).all()

    run()


# ---------------------------------------------------------------------------------------------- V2X
@pytest.fixture(scope="module")
def unit(work: Path) -> Path:
    keygen(work / "keys", "rsu")
    return work / "keys"


def _alert(station_id: int, now_s: float) -> Alert:
    return Alert.from_physical(
        station_id=station_id,
        generation_time_s=now_s,
        sequence=5,
        lat_deg=59.437,
        lon_deg=24.7536,
        heading_deg=90.0,
        speed_mps=14.0,
        siren=True,
        lights=True,
    )


_FIELDS = struct.Struct(">" + "B" * ALERT_SIZE)


@st.composite
def mutated_alert(draw: st.DrawFn, body: bytes) -> bytes:
    """An alert body with one to three bytes set to arbitrary values (every field reachable), or
    any other byte string."""
    data = bytearray(body)
    for _ in range(draw(st.integers(1, 3))):
        data[draw(st.integers(0, ALERT_SIZE - 1))] = draw(st.integers(0, 255))
    return bytes(data)


def test_fuzz_alert_body(unit: Path) -> None:
    ident = load_identity(unit / "rsu.key")
    body = encode_alert(_alert(ident.station_id, 1.764e9))
    assert len(_FIELDS.unpack(body)) == ALERT_SIZE

    @budget(2.0)
    @given(data=mutated_alert(body) | mutated_bytes(body) | st.binary(max_size=2 * ALERT_SIZE))
    def run(data: bytes) -> None:
        got = check_reader("V2X alert body", lambda: decode_alert(data), allowed=(MalformedAlertError,))
        if got is not None:  # a body that decodes encodes back to the same bytes
            assert encode_alert(got) == data

    run()


def test_fuzz_signed_alert(unit: Path) -> None:
    """What a car receives: any byte string gets a verdict, never an exception; a tampered message is
    never accepted, however the tampering was done (re-signed fields with other values are)."""
    ident = load_identity(unit / "rsu.key")
    now = 1.764e9
    store = TrustStore.load(unit / "trust")
    signed = sign_alert(_alert(ident.station_id, now), ident)

    at = 7  # the DENM follows 7 bytes of 1609.2 header (makeway.v2x.security)
    assert signed[at : at + ALERT_SIZE] == encode_alert(_alert(ident.station_id, now))

    @st.composite
    def resigned(draw: st.DrawFn) -> bytes:
        body = draw(mutated_alert(signed[at : at + ALERT_SIZE]))
        unsigned = signed[:at] + body + signed[at + ALERT_SIZE :]
        try:
            alert = decode_alert(body)
        except MalformedAlertError:
            return unsigned
        if alert.station_id != ident.station_id:
            return unsigned
        return sign_alert(alert, ident)

    @budget(1.0)
    @given(data=resigned() | mutated_bytes(signed) | st.binary(max_size=256))
    def run(data: bytes) -> None:
        verifier = Verifier(store)
        got = check_reader("V2X signed alert", lambda: verifier.verify(data, now), allowed=())
        assert isinstance(got, Verdict)
        if got.valid:
            assert data[-64:] != signed[-64:] or data == signed  # no forged acceptance

    run()


def test_fuzz_key_and_certificate(unit: Path, work: Path) -> None:
    seeds = {"rsu.key": (unit / "rsu.key").read_bytes(), "rsu.cert": (unit / "rsu.cert").read_bytes()}
    kinds = {"rsu.key": "text", "rsu.cert": "binary"}  # a PEM key, a 1609.2 certificate in COER
    folder = work / "identity"

    @budget(0.5)
    @given(member=st.sampled_from(sorted(seeds)), data=st.data())
    def run(member: str, data: st.DataObject) -> None:
        for name, seed in seeds.items():
            _write(folder, name, seed)
        _write(folder, member, data.draw(file_contents(seeds[member], kinds[member])))
        check_reader(f"V2X identity ({member[4:]})", lambda: load_identity(folder / "rsu.key"), inside=folder)

    run()


def test_fuzz_trust_store(unit: Path, work: Path) -> None:
    trust = unit / "trust"
    members = ["root.cert", "units/rsu.cert", "revoked.txt"]
    seeds = {m: (trust / m).read_bytes() if (trust / m).exists() else b"" for m in members}
    seeds["revoked.txt"] += b"0011223344556677  # a unit\n"
    folder = work / "trust"

    @budget(0.5)
    @given(member=st.sampled_from(members), data=st.data())
    def run(member: str, data: st.DataObject) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        for name, seed in seeds.items():
            _write(folder / Path(name).parent, Path(name).name, seed)
        kind = "text" if member.endswith(".txt") else "binary"
        _write(folder / Path(member).parent, Path(member).name, data.draw(file_contents(seeds[member], kind)))
        check_reader(f"V2X trust store ({Path(member).name})", lambda: TrustStore.load(folder), inside=folder)

    run()


# ----------------------------------------------------------------------- regressions found by fuzzing
# the DER of the OID id-ecPublicKey (1.2.840.10045.2.1), inside a PKCS#8 private key
EC_PUBLIC_KEY = bytes.fromhex("06072a8648ce3d0201")


def _edit(data: bytes, at: int, new: bytes) -> bytes:
    return data[:at] + new + data[at + len(new) :]


@pytest.mark.parametrize(
    "what",
    ["version 2", "not on the curve", "an X.509 PEM certificate", "trailing byte", "no DENM permission"],
)
def test_damaged_certificate_is_one_input_error(unit: Path, work: Path, what: str) -> None:
    """A damaged or foreign certificate, as the unit's and as the root, is one InputError naming the
    file: a version other than 3, a verification key whose x has no point on P-256, the PEM X.509
    certificate of an older makeway, one byte too many (COER must match its re-encoding), a unit
    certificate without PSID 37."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    from makeway.v2x.certificates import issue_certificate, parse_certificate

    folder = work / f"damaged_{what.replace(' ', '_')}"
    shutil.rmtree(folder, ignore_errors=True)
    shutil.copytree(unit, folder)
    cert, root = (folder / "rsu.cert").read_bytes(), (folder / "trust" / "root.cert").read_bytes()

    def damage(data: bytes) -> bytes:
        if what == "version 2":
            assert data[1] == 3
            return _edit(data, 1, b"\x02")
        if what == "not on the curve":  # x = 5: 5³ − 3·5 + b is not a square mod p
            x = parse_certificate(data).public_key.public_numbers().x.to_bytes(32, "big")
            return data.replace(x, (5).to_bytes(32, "big"))
        if what == "an X.509 PEM certificate":
            return b"-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n"
        if what == "trailing byte":
            return data + b"\x00"
        # "no DENM permission": the unit's own key in a self-signed root certificate, not a unit's
        key = serialization.load_pem_private_key((folder / "rsu.key").read_bytes(), password=None)
        assert isinstance(key, ec.EllipticCurvePrivateKey)
        return issue_certificate(
            "x", key.public_key(), key, issuer=None, start_s=time.time(), days=1, can_issue=True
        ).data

    (folder / "rsu.cert").write_bytes(damage(cert))
    with pytest.raises(InputError) as info:
        load_identity(folder / "rsu.key")
    assert info.value.path == folder / "rsu.cert"
    if what == "no DENM permission":
        assert "PSID 37" in str(info.value)
        return
    (folder / "trust" / "root.cert").write_bytes(damage(root))
    with pytest.raises(InputError) as info:
        TrustStore.load(folder / "trust")
    assert info.value.path == folder / "trust" / "root.cert"


def test_revocation_list_not_utf8(unit: Path, work: Path) -> None:
    """Found by fuzzing: a revoked.txt that is not UTF-8 raised UnicodeDecodeError."""
    folder = work / "revoked_not_utf8"
    shutil.copytree(unit / "trust", folder)
    (folder / "revoked.txt").write_bytes(b"\x80")
    with pytest.raises(InputError, match="cannot be read as a revocation list") as info:
        TrustStore.load(folder)
    assert info.value.path == folder / "revoked.txt"


def test_damaged_torch_weights_are_one_input_error(torch_weights: dict[str, bytes], work: Path) -> None:
    """Found by fuzzing: a zip whose CRC or directory is damaged raised zipfile.BadZipFile, pickle's
    message for a stray persistent-id opcode spans two lines, and a pickle announcing more bytes than
    memory holds raised MemoryError."""
    raw = torch_weights["zip"]
    at = raw.index(b"conv.weight")
    crc = raw[:at] + bytes([raw[at] ^ 1]) + raw[at + 1 :]  # the pickle's bytes change, its CRC does not
    central = raw.replace(b"PK\x01\x02", b"QK\x01\x02", 1)  # the central directory's magic
    # a legacy file whose first pickle is a BINBYTES8 announcing 2**62 bytes: MemoryError
    huge = b"\x80\x02\x8e" + (2**62).to_bytes(8, "little") + b"."
    for name, data in (("crc", crc), ("central", central), ("persistent_id", b"P"), ("huge", huge)):
        path = _write(work / "torch_regressions", f"{name}.pt", data)
        with pytest.raises(InputError, match="not a readable PyTorch state dict") as info:
            read_torch_state_dict(path)
        assert info.value.path == path and "\n" not in str(info.value)


def test_torch_weights_cannot_run_code(work: Path) -> None:
    """Found by fuzzing (a GLOBAL opcode importing module ``t``): the legacy format's header pickles
    were read with plain ``pickle.load``, so a crafted weights file could import and call anything.
    Here a file whose first pickle calls ``os.mkdir``: refused, and nothing is made."""
    made = work / "made_by_a_weights_file"
    payload = b"cos\nmkdir\n(V" + str(made).encode() + b"\ntR."
    path = _write(work / "torch_regressions", "crafted.pt", payload)
    with pytest.raises(InputError, match=r"found a reference to os\.mkdir") as info:
        read_torch_state_dict(path)
    assert info.value.path == path
    assert not made.exists()


def test_key_of_an_unknown_type_is_one_input_error(unit: Path, work: Path) -> None:
    """Found by fuzzing: a PEM private key whose algorithm OID is unknown raised UnsupportedAlgorithm."""
    import base64

    pem = (unit / "rsu.key").read_bytes()
    der = base64.b64decode(b"".join(line for line in pem.splitlines() if not line.startswith(b"-----")))
    der = der.replace(EC_PUBLIC_KEY, EC_PUBLIC_KEY[:-1] + b"\x09", 1)
    folder = work / "unknown_key_type"
    shutil.copytree(unit, folder)
    body = base64.encodebytes(der)
    (folder / "rsu.key").write_bytes(b"-----BEGIN PRIVATE KEY-----\n" + body + b"-----END PRIVATE KEY-----\n")
    with pytest.raises(InputError, match="not an unencrypted PEM private key") as info:
        load_identity(folder / "rsu.key")
    assert info.value.path == folder / "rsu.key"
