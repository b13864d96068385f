//! Typed layouts of the wireless commands.
