"""Bus tools: the socketcand loopback hub (:mod:`.hub`), bus recording and replay (:mod:`.recorder`), the
DBC generated from the PDO mapping (:mod:`.dbc`) and the bus-load calculation (:mod:`.busload`)."""
