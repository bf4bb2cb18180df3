"""Delivered products read as sensors and control: ancillary files, scene folders."""
