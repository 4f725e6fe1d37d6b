"""One base station: everything of the gateway that belongs to one serial port (its port
and link, reader, scheduler, supervisor, nodes and their clocks, line load, replay).
:class:`.station.Station` holds them; nothing here imports an output (:mod:`.outlet`
says what a station hands out)."""
