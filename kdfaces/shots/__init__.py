"""Shots: TOML shot files (rig, animation, dynamics, constraints, solver), running them (KD of every frame, the
IKD solve), rendering them, authoring their constraints (:class:`AuthoringSession`), and the built-in demo shot
``demo.toml``."""

from .authoring import AuthoringSession, Outcome, Row
from .builtin import DEMO_SHOT, demo_animation
from .demo import run_demo
from .render import render_shot
from .run import ShotRun, run_shot, run_summary, write_run_outputs
from .shotfile import Shot, WorkEstimate, estimate_work, load_shot, parse_shot
from .view import add_view_parser, view_shot

__all__ = ["DEMO_SHOT", "demo_animation", "run_demo", "render_shot", "ShotRun", "run_shot", "run_summary",
           "write_run_outputs", "Shot", "load_shot", "parse_shot", "view_shot", "add_view_parser",
           "WorkEstimate", "estimate_work", "AuthoringSession", "Outcome", "Row"]
