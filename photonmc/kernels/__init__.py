"""Taichi building blocks (@ti.func) shared by every method."""
