"""One :class:`~cylindersplat.dataset_layouts.DatasetSpec` per dataset layout, one module each; the registry
(:data:`cylindersplat.dataset_layouts.DATASET_SPECS`) names them. Loaders are imported inside the functions, so
detecting a layout stays cheap."""
