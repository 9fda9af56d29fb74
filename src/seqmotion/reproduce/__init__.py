"""One module per chapter: ``seqmotion reproduce chN`` runs ``seqmotion.reproduce.chN.run``."""
