"""The live view: a page on 127.0.0.1 that shows the validator's reports as they come.

ROS-free, above the layers that make the reports: a listener of the same
:class:`~twotank_validation.online.validator.OnlineValidator` path (``live``'s ``on_report``,
``validate``'s streamed reports), not a second computation. :mod:`.messages` turns a
:class:`~twotank_validation.online.window.WindowReport` into the JSON the page gets (the
``validate --json`` window entry, with the model's name and the per-bin spectrum);
:mod:`.server` serves the page and pushes each message (Server-Sent Events, stdlib);
:mod:`.pacing` paces a replay at a multiple of real time; :mod:`.response` turns an
``identify --json`` file into the page's identified response. docs/view.md.
"""

from twotank_validation.view.messages import report_message, spectrum
from twotank_validation.view.pacing import Pacer
from twotank_validation.view.server import DEFAULT_HISTORY, ViewServer

__all__ = ["DEFAULT_HISTORY", "Pacer", "ViewServer", "report_message", "spectrum"]
