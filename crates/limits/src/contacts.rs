//! Contacts: how many fingers one message, one source and one datagram may
//! hold down. A hand has ten fingers and a table a few dozen; a message past
//! these is refused whole, never cut (a cut frame would drop an up).
