"""CiA 402 (IEC 61800-7 drive profile) between the NC and its drives.

The layers, each one place (issue 20):

* :mod:`.objects`   object dictionary indices, modes of operation, controlword / statusword bits;
* :mod:`.statemachine`  the power state machine, pure and vectorized: the device side (controlword ->
  state) and the NC side (state + what the NC wants -> next controlword);
* :mod:`.image`     the cyclic process data (RxPDO/TxPDO images, one column per axis) and the
  :class:`~.image.ProcessDataLink` a fieldbus implements (in process, CANopen, zenoh to ``nc-drive-sim``);
* :mod:`.drive`     :class:`~.drive.Cia402Drive`: the NC's ``DriveABC`` on top of any link (enables,
  fault reset, encoder chain, drive errors -> NC axis errors);
* :mod:`.device`    :class:`~.device.Cia402Device`: simulated CiA 402 drives (state machine, CSP/CSV,
  quick stop, the mechanical model), used by ``cia402-sim``, the simulated CANopen slaves and ``nc-drive-sim``.

It may import: numpy, nc_schema, nc_server.core.params, nc_server.drives.
"""
