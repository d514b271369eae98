//! Parameter storage behind a small trait: the board's non-volatile copy of the 20-byte
//! parameter block (SPEC.md §4.1, §5 SAVE_PARAMS), and [`RamStorage`] for boards without one.

use crate::message::ParamsBlock;

/// Writing the stored copy failed; the old copy is still the stored one (NACK
/// STORAGE_FAILURE).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the parameter copy could not be written or verified")]
pub struct StorageError;

/// Non-volatile storage of the parameter block, as the board provides it.
///
/// SPEC.md asks for atomic writes: the block and its CRC go to the inactive one of two slots,
/// are read back and verified, and only then does that slot become current (a generation
/// counter picks the current slot at power-up). A power loss at any moment leaves the old or
/// the new copy, never a mix.
pub trait ParamStorage {
    /// Whether the copy survives a power cycle (HELLO capability bit 3).
    const NON_VOLATILE: bool = true;

    /// The stored copy, if a valid one exists (its CRC checked). Called at power-up.
    fn load(&mut self) -> Option<ParamsBlock>;

    /// Writes `block` atomically and verifies it. On error the previous copy must remain.
    fn save(&mut self, block: &ParamsBlock) -> Result<(), StorageError>;
}

/// A stored copy kept in RAM: it survives [`super::Device::power_cycle`] but not a real power
/// loss (capability bit 3 is not reported).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RamStorage(pub Option<ParamsBlock>);

impl ParamStorage for RamStorage {
    const NON_VOLATILE: bool = false;

    fn load(&mut self) -> Option<ParamsBlock> {
        self.0
    }

    fn save(&mut self, block: &ParamsBlock) -> Result<(), StorageError> {
        self.0 = Some(*block);
        Ok(())
    }
}
