"""The data engine (issue 28, seed 000's loop at fleet scale): mine many logs, videos, image folders
and recordings for hard samples on a Dask cluster, rank them for review, and feed the labels back.

* :mod:`makeway.engine.inputs` — what an input is (a video, a frame range of one, a folder of road
  images, a multichannel recording) and the registry of input kinds;
* :mod:`makeway.engine.mine` — the per-input task: run the vision and siren models, keep the hard
  samples with their context, write them atomically with a done-marker;
* :mod:`makeway.engine.cluster` — the Dask side: a local cluster or an existing scheduler, the job
  over all inputs with a progress bar, failures listed, the ranked review at the end;
* :mod:`makeway.engine.feedback` — labelled samples back into a crop folder and the before/after
  of the retrained model on the cross-source protocol.
"""
