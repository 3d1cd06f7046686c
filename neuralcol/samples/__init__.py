"""D_c and its sampling in one place: the HDF5 store of labeled latent samples (:mod:`.store`), the cached
pools of uniform samples and the shared test set (:mod:`.uniform`, :mod:`.test_set`), the exact oracle that
decodes codes and labels them (:mod:`.oracle`) and the LightningDataModule that serves D_c to the detector
(:mod:`.datamodule`)."""
