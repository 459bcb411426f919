"""Building faces from raw data: scan preprocessing (crop, grid resampling, normalisation) and the
average face model."""
