"""Packets a robot would send, made from the fake scene, and a database filled with them."""
from btf.fit.dependence import measure
from btf.fit.fitter import FrameFitter
from hal.interfaces import ViewAngles
from hal.scene import render
from radio import packets as pk
from tools.station.receiver import Receiver
from tools.store.database import Store


def models_body(seq, elevation=60.0, scene="mixed", extras=None, space="rgb", dependence=None):
    """A MODELS body of robot 3 seeing `scene` at `elevation`, its fitted models and the true label map."""
    view = render(scene, ViewAngles(elevation, 0.0), (40, 48), seed=0)
    f = FrameFitter(4, 3)
    f.add(view.image, view.mask)
    fits = f.fit()
    bands = ("R", "G", "B") if space == "rgb" else ("P1", "P2", "P3")
    body = pk.encode_models(fits, robot_id=3, seq=seq, time=100.0 + seq, commanded=(elevation, 0.0),
                            measured=(elevation + 0.2, 0.1), feature_space=space, bands=bands,
                            extras=extras, dependence=dependence)
    return body, fits, view.mask


def dependence_body(seq, elevation=60.0):
    """A MODELS body carrying the dependence measured on its own view, and that dependence."""
    view = render("mixed", ViewAngles(elevation, 0.0), (40, 48), seed=0)
    _, fits, _ = models_body(seq, elevation)
    deps = measure(view.image, view.mask, {k: r.model for k, r in fits.items()})
    return models_body(seq, elevation, dependence=deps)[0], deps


def filled_database(path):
    """A database of two captures of the mixed plate, the first with its label map."""
    with Store.open(path) as s:
        rx = Receiver(s, scene="mixed")
        body, _, mask = models_body(1, 50.0)
        rx.handle(pk.encode_mask(mask, robot_id=3, seq=1))
        rx.handle(body)
        rx.handle(models_body(2, 70.0)[0])  # no mask of its own: uses capture 1's
    return path
