"""Models across the border: export to the physical car, DeepRacer-on-AWS and DRfC; import their models; S3.

    >>> from racerlab.exchange import export_car, export_droa, export_drfc, import_model
    >>> export_car("models/mine")                    # mine-car.tar.gz: model_metadata.json + agent/model.pb
    >>> export_droa("models/mine")                   # mine-droa.tar.gz: DRoA's "Import model" tree
    >>> import_model("console-model.tar.gz", "models/console")

Modules: `coach` (rl_coach names and TF layouts), `graphdef` (frozen model.pb without TensorFlow),
`tfckpt` (TF checkpoints, with TensorFlow), `export`, `importer`, `s3`, and `local` (racerlab's side).
See docs/exchange.md.
"""

from racerlab.exchange.export import export_car, export_drfc, export_droa, frozen_graph
from racerlab.exchange.importer import import_model, safe_extract

__all__ = ["export_car", "export_drfc", "export_droa", "frozen_graph", "import_model", "safe_extract"]
