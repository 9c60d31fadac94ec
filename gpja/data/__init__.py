"""Datasets: FaceScape-layout reading and the synthetic benchmark generator."""
