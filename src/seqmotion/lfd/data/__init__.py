"""The demonstrations: the HDF5 datasets and their collection (:mod:`.dataset`), LeRobotDataset v3.0 export
(:mod:`.lerobot`) and import (:mod:`.lerobot_import`), slicing them for training (:mod:`.slicing`) and
rendering training frames from them (:mod:`.frames`)."""
