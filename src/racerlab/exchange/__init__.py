"""Models across the border: export to the physical car, DeepRacer-on-AWS and DRfC; import their models; S3.

    >>> from racerlab.exchange import export_car, export_droa, export_drfc, import_model
    >>> export_car("models/mine")                    # mine-car.tar.gz: model_metadata.json + agent/model.pb
    >>> export_droa("models/mine")                   # mine-droa.tar.gz: DRoA's "Import model" tree
    >>> export_onnx("models/mine")                   # mine-onnx.tar.gz: model_metadata.json + model.onnx
    >>> export_tflite("models/mine")                 # mine-tflite.tar.gz: the community car's model folder
    >>> import_model("console-model.tar.gz", "models/console")

Modules: `coach` (rl_coach names and TF layouts), `graphdef` (frozen model.pb without TensorFlow),
`onnxgraph` (the same policy as ONNX), `tflite` (TensorFlow's converter, as the community car calls it),
`runtimes` (onnxruntime, TFLite and OpenVINO runners), `tfckpt` (TF checkpoints, with TensorFlow), `export`,
`importer`, `s3`, and `local` (racerlab's side).
See docs/exchange.md.
"""

from racerlab.exchange.export import export_car, export_drfc, export_droa, export_onnx, export_tflite, frozen_graph
from racerlab.exchange.importer import import_model, safe_extract

__all__ = ["export_car", "export_drfc", "export_droa", "export_onnx", "export_tflite", "frozen_graph", "import_model",
           "safe_extract"]
