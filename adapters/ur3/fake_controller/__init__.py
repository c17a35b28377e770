"""A fake Universal Robots controller on the network, for driving the real ur_rtde client.

It listens on one loopback address, on the controller's fixed ports:

* **30004, RTDE**: protocol version 2 (``V``), controller version (``v``), output and
  input recipe setup (``O``/``I``), start/pause (``S``/``P``), and data packages
  (``U``) both ways; every package starts with the header ``>HB`` (uint16 size
  including the header, uint8 command). Output packages are streamed to each started
  client from the simulated robot state.
* **30003, script**: accepts the URScript program a client writes. A program that
  reads the command register (``read_input_integer_register``) is taken to be
  ur_rtde's control script: the fake then plays that script's side of the register
  handshake (see :class:`~.script.ControlScript`).
* **29999, dashboard**: the welcome line and the few queries ur_rtde makes.
* **a JSON control channel** (``--control-port``, default 30999) for tests: read the
  state and the log of commands received, trigger a protective stop, an emergency
  stop or a dropped connection, and shut down. One JSON object per line each way.

The simulated robot has a TCP pose that ``moveL`` moves along a straight line with a
trapezoidal speed profile (optionally faster than real time, ``--time-scale``), robot
mode, safety mode/status bits, runtime state, digital outputs, protective and
emergency stops, and a link that can drop.

It must run in its own process: ur_rtde's constructors hold the GIL while they wait
for the controller, so a fake in a thread of the client's process deadlocks.

Examples
--------
``python -m adapters.ur3.fake_controller --host 127.0.0.2 --time-scale 0.2``

Modules: :mod:`.rtde` (the RTDE wire format), :mod:`.robot` (the simulated arm),
:mod:`.script` (ur_rtde's control script, played), :mod:`.controller` (the servers, the
command log and the test control channel), ``__main__`` (the command line).
"""
