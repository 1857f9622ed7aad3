"""One writer per fabrication process behind one interface
(:class:`~.base.ProcessWriter`): :mod:`.fdm_dual`, :mod:`.laser_epdm` and :mod:`.plywood_cnc`,
with what they share in :mod:`.print_jobs` (3MF print jobs) and :mod:`.strips` (rubber strips
cut from sheet).  :data:`drawstring.fabrication.exports.WRITERS` picks one by the profile's
process.  The writers load the CAD kernel, so nothing is imported here."""
